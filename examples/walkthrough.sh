#!/usr/bin/env bash
# From a fresh start to the pictures, through the REST API with curl:
#
#   1. start `eyekey serve` on a temporary data directory and a free port;
#   2. enrol the target's vision profile, and a representative observer the encoder keeps the document from;
#   3. register a display (the `lenslet` preset: 48×48 lenslets of 1 mm, 9×9 views, 4 projectors, which
#      resolves its views under diffraction; jobs are encoded under wave optics);
#   4. upload the PIN slip and create a job; follow it until it succeeds;
#   5. download the frame bundle with the display's own token, and let the display client install it;
#   6. simulate what the target sees, and what a bystander sees: a third person the server has never heard of.
#
# Run from anywhere after `cargo build --release`:   examples/walkthrough.sh
# Environment: EYEKEY (the binary, default ./target/release/eyekey), WORK (output directory, default a new
# temporary one), PRESET (display preset, default lenslet).
# Needs curl, and jq or python3 to read JSON.

set -euo pipefail
export LC_ALL=C
cd "$(dirname "$0")/.."

EYEKEY=${EYEKEY:-./target/release/eyekey}
PRESET=${PRESET:-lenslet}
WORK=${WORK:-$(mktemp -d "${TMPDIR:-/tmp}/eyekey-walkthrough.XXXXXX")}
DATA="$WORK/data"
mkdir -p "$WORK"

say() { printf '\n== %s\n' "$*"; }
die() { printf 'walkthrough: %s\n' "$*" >&2; exit 1; }

[ -x "$EYEKEY" ] || die "no eyekey binary at $EYEKEY: run 'cargo build --release' first (or set EYEKEY)"
command -v curl >/dev/null || die "curl is needed"

# json PATH: reads JSON on stdin and prints one field; PATH is a simple jq path (.display.id, .items[0].id).
if command -v jq >/dev/null; then
    json() { jq -r "$1"; }
elif command -v python3 >/dev/null; then
    json() {
        python3 -c '
import json, re, sys
v = json.load(sys.stdin)
for name, index in re.findall(r"\.(\w+)|\[(\d+)\]", sys.argv[1]):
    v = v[int(index)] if index else v[name]
print(json.dumps(v) if isinstance(v, (dict, list)) else ("null" if v is None else str(v).lower() if isinstance(v, bool) else v))' "$1"
    }
else
    die "jq or python3 is needed to read JSON"
fi

START=$(date +%s)

say "1. Starting the server (data in $DATA)"
"$EYEKEY" serve --bind 127.0.0.1:0 --data-dir "$DATA" 2>"$WORK/server.log" &
SERVER_PID=$!
stop_server() {
    if kill -0 "$SERVER_PID" 2>/dev/null; then
        kill -TERM "$SERVER_PID" 2>/dev/null || true
        wait "$SERVER_PID" 2>/dev/null || true
    fi
}
trap stop_server EXIT

# The server says where it listens on stderr; port 0 let the system pick a free port.
URL=""
for _ in $(seq 1 100); do
    URL=$(sed -n 's/.*eyekey serving on \(http:[^ ]*\).*/\1/p' "$WORK/server.log" | head -n 1)
    [ -n "$URL" ] && break
    kill -0 "$SERVER_PID" 2>/dev/null || { cat "$WORK/server.log" >&2; die "the server did not start"; }
    sleep 0.1
done
[ -n "$URL" ] || die "the server did not report its address; see $WORK/server.log"
curl -fsS "$URL/readyz" >/dev/null || die "the server is not ready; see $WORK/server.log"
OP=$(cat "$DATA/operator-token")
echo "server at $URL; the operator token was generated into $DATA/operator-token"

# op METHOD PATH [curl args...]: an operator request; fails on an HTTP error and shows the server's message.
op() {
    local method=$1 path=$2
    shift 2
    local body status
    body=$(curl -sS -X "$method" -H "Authorization: Bearer $OP" -w '\n%{http_code}' "$@" "$URL$path")
    status=${body##*$'\n'}
    body=${body%$'\n'*}
    case $status in
        2??) printf '%s' "$body" ;;
        *) die "$method $path answered $status: $body" ;;
    esac
}
post_json() { op POST "$1" -H 'Content-Type: application/json' --data-binary "$2"; }

say "2. Enrolling the target and a representative observer"
TARGET=$(post_json /v1/profiles "{\"label\": \"target\", \"profile\": $(cat examples/profiles/target.json)}" | json .id)
REPRESENTATIVE=$(post_json /v1/profiles \
    "{\"label\": \"representative observer\", \"profile\": $(cat examples/profiles/representative.json)}" | json .id)
echo "target profile $TARGET, representative profile $REPRESENTATIVE"

say "3. Registering a display (preset $PRESET)"
DISPLAY_JSON=$(post_json /v1/displays "{\"name\": \"walkthrough display\", \"preset\": \"$PRESET\"}")
DISPLAY_ID=$(printf '%s' "$DISPLAY_JSON" | json .display.id)
DISPLAY_TOKEN=$(printf '%s' "$DISPLAY_JSON" | json .token)
echo "display $DISPLAY_ID; its token is shown only this once (kept in this shell only)"

say "4. Uploading the PIN slip and creating a job"
DOCUMENT=$(op POST /v1/documents -H 'Content-Type: image/png' --data-binary @examples/documents/pin_slip.png | json .id)
JOB=$(post_json /v1/jobs "{
    \"display_id\": \"$DISPLAY_ID\",
    \"document_id\": \"$DOCUMENT\",
    \"profile_id\": \"$TARGET\",
    \"observer_profile_ids\": [\"$REPRESENTATIVE\"],
    \"options\": {\"evaluation_population\": 5}
}" | json .id)
echo "job $JOB queued"
while :; do
    JOB_JSON=$(op GET "/v1/jobs/$JOB")
    STATE=$(printf '%s' "$JOB_JSON" | json .state)
    PROGRESS=$(printf '%s' "$JOB_JSON" | json .progress)
    printf '\r  %-9s %5.1f %%' "$STATE" "$(awk "BEGIN {print 100 * $PROGRESS}")"
    case $STATE in
        succeeded) echo; break ;;
        failed | cancelled) echo; die "the job ended $STATE: $(printf '%s' "$JOB_JSON" | json .last_error)" ;;
    esac
    sleep 1
done
EVALUATION=$(op GET "/v1/jobs/$JOB/evaluation")
echo "the server's evaluation (legibility 0..1):"
printf '  target                   %.2f: %s (it must reach %.2f)\n' "$(printf '%s' "$EVALUATION" | json .target.legibility)" \
    "$(printf '%s' "$EVALUATION" | json .target_reading.reads | sed 's/true/reads it/; s/false/does not read it/')" \
    "$(printf '%s' "$EVALUATION" | json .target_reading.bar)"
printf '  representative observer  %.2f (somebody might read from %.2f)\n' \
    "$(printf '%s' "$EVALUATION" | json ".observers[0].legibility")" "$(printf '%s' "$EVALUATION" | json .threshold)"

say "5. Downloading the bundle with the display's token"
curl -fsS -H "Authorization: Bearer $DISPLAY_TOKEN" -o "$WORK/bundle.zip" "$URL/v1/frames/jobs/$JOB/bundle.zip"
echo "bundle: $WORK/bundle.zip ($(wc -c <"$WORK/bundle.zip") bytes)"
# The display client does the same, verifies the bundle and installs it where a projector rig reads it.
EYEKEY_DISPLAY_TOKEN=$DISPLAY_TOKEN RUST_LOG=warn \
    "$EYEKEY" display-client --once --server "$URL" --out "$WORK/display"

say "6. What the target and a bystander see"
"$EYEKEY" simulate --display "examples/displays/$PRESET.json" --profile examples/profiles/target.json \
    --frames "$WORK/bundle.zip" --out "$WORK/target_sees.png"
# The bystander's profile was never given to the server: the encoder could not tune against this person.
"$EYEKEY" simulate --display "examples/displays/$PRESET.json" --profile examples/profiles/other.json \
    --frames "$WORK/bundle.zip" --out "$WORK/bystander_sees.png"

stop_server
trap - EXIT
say "Done in $(($(date +%s) - START)) s"
cat <<EOF
  what the target sees:    $WORK/target_sees.png
  what a bystander sees:   $WORK/bystander_sees.png
  the document:            examples/documents/pin_slip.png
  the frames, as a display client installed them:  $WORK/display/current/
  server log:              $WORK/server.log
EOF
