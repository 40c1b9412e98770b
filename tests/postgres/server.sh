#!/usr/bin/env bash
# A throwaway PostgreSQL server for eyekey's tests and benchmarks, on 127.0.0.1 and a free port.
#
#   server.sh install              installs Debian's postgresql package when initdb is missing (as root)
#   server.sh start DIR [PID]      initdb into DIR, start the server, print its URL on stdout; with PID, a
#                                  watcher stops the server and removes DIR once that process has ended
#   server.sh stop DIR             stops the server and removes DIR
#
# The cluster trusts connections from 127.0.0.1 as user "eyekey" (a throwaway server in a 0700 directory;
# no other address is listened on). As root, the server runs as the "postgres" user that the package
# creates, since PostgreSQL refuses to run as root. fsync is off: the tests kill workers, never this server.
set -euo pipefail

bindir() {
    local d
    d=$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -n 1 || true)
    if [[ -z "$d" || ! -x "$d/initdb" ]]; then
        return 1
    fi
    echo "$d"
}

install() {
    if bindir >/dev/null; then
        return 0
    fi
    if [[ $(id -u) -ne 0 ]]; then
        echo "PostgreSQL is not installed and installing it needs root: apt-get install postgresql" >&2
        exit 1
    fi
    echo "installing postgresql (Debian package)" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >&2
    apt-get install -y -qq --no-install-recommends postgresql >&2
    bindir >/dev/null || { echo "postgresql installed but initdb not found" >&2; exit 1; }
}

# Runs a command as the server's owner.
as_owner() {
    if [[ $(id -u) -eq 0 ]]; then
        runuser -u postgres -- "$@"
    else
        "$@"
    fi
}

start() {
    local dir=$1 watch=${2:-}
    install
    local bin
    bin=$(bindir)
    mkdir -p "$dir"
    chmod 700 "$dir"
    if [[ $(id -u) -eq 0 ]]; then
        chown postgres: "$dir"
    fi
    as_owner "$bin/initdb" -D "$dir/data" -U eyekey --auth=trust --encoding=UTF8 --no-sync >"$dir/initdb.log" 2>&1 \
        || { cat "$dir/initdb.log" >&2; exit 1; }
    local port started=""
    for _ in $(seq 1 20); do
        port=$(shuf -i 20000-60000 -n 1)
        if as_owner "$bin/pg_ctl" -D "$dir/data" -l "$dir/server.log" -w -t 30 \
            -o "-c listen_addresses=127.0.0.1 -p $port -k $dir -c fsync=off -c max_connections=200" \
            start >/dev/null 2>&1; then
            started=1
            break
        fi
    done
    if [[ -z "$started" ]]; then
        echo "could not start PostgreSQL; its log:" >&2
        cat "$dir/server.log" >&2 || true
        exit 1
    fi
    if [[ -n "$watch" ]]; then
        # Detached from the caller's output, so the caller's pipes close when it is done.
        nohup bash -c "while kill -0 $watch 2>/dev/null; do sleep 1; done; \"$0\" stop \"$dir\"" \
            >/dev/null 2>&1 </dev/null &
    fi
    echo "postgres://eyekey@127.0.0.1:$port/postgres"
}

stop() {
    local dir=$1 bin
    bin=$(bindir) || exit 0
    if [[ -f "$dir/data/postmaster.pid" ]]; then
        as_owner "$bin/pg_ctl" -D "$dir/data" -m fast -w stop >/dev/null 2>&1 || true
    fi
    rm -rf "$dir"
}

case "${1:-}" in
    install) install ;;
    start) start "${2:?usage: server.sh start DIR [PID]}" "${3:-}" ;;
    stop) stop "${2:?usage: server.sh stop DIR}" ;;
    *) echo "usage: server.sh install | start DIR [PID] | stop DIR" >&2; exit 2 ;;
esac
