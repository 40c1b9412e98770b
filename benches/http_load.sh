#!/usr/bin/env bash
# GET job status under load (wrk) while a solver job keeps every core busy, and bundle download throughput,
# against the release binary on loopback. Installs wrk from Debian's packages if missing.
# Usage: bash benches/http_load.sh        Figures go to BENCHMARKS.md (section "http").
set -euo pipefail
cd "$(dirname "$0")/.."
command -v wrk >/dev/null || { apt-get update -qq && apt-get install -y -qq wrk >/dev/null; }
cargo build --release -q
E=./target/release/eyekey
work=$(mktemp -d)
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
$E serve --bind 127.0.0.1:$port --data-dir "$work/data" --workers 1 >"$work/server.log" 2>&1 &
server=$!
trap 'kill $server 2>/dev/null; wait $server 2>/dev/null; rm -rf "$work"' EXIT
for _ in $(seq 100); do curl -fs "http://127.0.0.1:$port/readyz" >/dev/null && break; sleep 0.1; done
base="http://127.0.0.1:$port"
op=$(cat "$work/data/operator-token")
json() { python3 -c "import json,sys; print(json.load(sys.stdin)$1)"; }
post() { curl -fsS -X POST -H "Authorization: Bearer $op" -H 'Content-Type: application/json' -d "$2" "$base$1"; }
profile=$($E example profile --population-seed 11)
pid=$(post /v1/profiles "{\"label\":\"bench\",\"profile\":$profile}" | json "['id']")
disp=$(post /v1/displays '{"name":"bench","preset":"paper"}')
did=$(echo "$disp" | json "['display']['id']"); dtoken=$(echo "$disp" | json "['token']")
$E example document --text PIN --text 4821 --width 200 --height 200 --out "$work/doc.png"
doc=$(curl -fsS -X POST -H "Authorization: Bearer $op" -H 'Content-Type: image/png' --data-binary @"$work/doc.png" "$base/v1/documents" | json "['id']")
# A long solve on the paper preset keeps the cores busy during the status benchmark.
busy=$(post /v1/jobs "{\"display_id\":\"$did\",\"document_id\":\"$doc\",\"profile_id\":\"$pid\",\"options\":{\"population_decoys\":8,\"max_iterations\":20000,\"tolerance\":1e-12,\"evaluation_population\":0}}" | json "['id']")
for _ in $(seq 200); do
  st=$(curl -fsS -H "Authorization: Bearer $op" "$base/v1/jobs/$busy" | json "['state']"); [ "$st" = running ] && break; sleep 0.2
done
cat >"$work/paced.lua" <<LUA
wrk.headers["Authorization"] = "Bearer $op"
-- 8 connections, each waiting 16 ms between requests: about 500 requests per second in all.
function delay() return 16 end
LUA
cat >"$work/auth.lua" <<LUA
wrk.headers["Authorization"] = "Bearer $op"
LUA
load=$(uptime | sed 's/.*load average: //')
paced=$(wrk -t2 -c8 -d20s --latency -s "$work/paced.lua" "$base/v1/jobs/$busy")
flat=$(wrk -t2 -c16 -d15s --latency -s "$work/auth.lua" "$base/v1/jobs/$busy")
echo "$paced"; echo "$flat"
curl -fsS -X POST -H "Authorization: Bearer $op" "$base/v1/jobs/$busy/cancel" >/dev/null
# A small job for the download benchmark.
small=$(post /v1/displays '{"name":"small","preset":"small"}')
sid=$(echo "$small" | json "['display']['id']"); stoken=$(echo "$small" | json "['token']")
$E example document --text 4821 --width 96 --height 96 --out "$work/doc2.png"
doc2=$(curl -fsS -X POST -H "Authorization: Bearer $op" -H 'Content-Type: image/png' --data-binary @"$work/doc2.png" "$base/v1/documents" | json "['id']")
job=$(post /v1/jobs "{\"display_id\":\"$sid\",\"document_id\":\"$doc2\",\"profile_id\":\"$pid\",\"options\":{\"max_iterations\":50,\"evaluation_population\":0}}" | json "['id']")
for _ in $(seq 600); do
  st=$(curl -fsS -H "Authorization: Bearer $op" "$base/v1/jobs/$job" | json "['state']"); [ "$st" = succeeded ] && break; sleep 0.2
done
size=$(curl -fsS -H "Authorization: Bearer $stoken" "$base/v1/frames/jobs/$job/bundle.zip" | wc -c)
cat >"$work/dl.lua" <<LUA
wrk.headers["Authorization"] = "Bearer $stoken"
LUA
dl=$(wrk -t2 -c4 -d10s -s "$work/dl.lua" "$base/v1/frames/jobs/$job/bundle.zip")
echo "$dl"
pct() { echo "$1" | awk -v p="$2" '$1==p {print $2}'; }
rps() { echo "$1" | awk '/Requests\/sec/ {print $2}'; }
body="Measured $(date -u '+%Y-%m-%d %H:%M UTC') by \`bash benches/http_load.sh\` (release binary, wrk $(wrk -v 2>&1 | head -1 | awk '{print $2}'), loopback).
GET /v1/jobs/{id} with the operator token while a paper-preset solve (8 decoys) ran on the only worker; load
average at the start: $load.

| load | requests/s | p50 | p99 |
| --- | --- | --- | --- |
| paced: 8 connections, 16 ms think time | $(rps "$paced") | $(pct "$paced" 50%) | $(pct "$paced" 99%) |
| unpaced: 16 connections | $(rps "$flat") | $(pct "$flat" 50%) | $(pct "$flat" 99%) |

Bundle download (\`small\` preset, $size bytes per zip, 4 connections, display token): $(rps "$dl") downloads/s,
$(echo "$dl" | awk '/Transfer\/sec/ {print $2}')/s.
"
echo "$body" | python3 benches/write_section.py http "HTTP service under load"
