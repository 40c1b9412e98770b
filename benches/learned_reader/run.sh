#!/usr/bin/env bash
# Trains and tests the learned readers (docs/experiments.md §0b) on the views `eyekey experiment reader-views`
# wrote: `benches/learned_reader/run.sh VIEWS_DIR [--train N ...] > table.md`. Makes its own virtualenv beside
# this script (or at $EYEKEY_READER_VENV) from requirements.txt on first use.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
venv="${EYEKEY_READER_VENV:-$here/.venv}"
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet -r "$here/requirements.txt"
fi
exec "$venv/bin/python" "$here/train.py" "$@"
