#!/usr/bin/env bash
# Calibrates the legibility threshold against OCR, the second attacker (docs/legibility-ocr.md); the known-font
# calibration itself (docs/legibility-calibration.md) comes from `eyekey experiment calibrate` alone.
#
#   bash benches/calibrate_ocr.sh [COUNT] [SEED]
#
# Installs tesseract (Debian package tesseract-ocr) if missing and a Python venv with Pillow and NumPy at
# benches/.venv, builds the release binary, writes COUNT simulated views with known PINs
# (`eyekey experiment calibrate`), OCRs each like an attacker would and writes docs/legibility-ocr.md.
set -euo pipefail
cd "$(dirname "$0")/.."

COUNT="${1:-400}"
SEED="${2:-1}"
JOBS="${JOBS:-$(nproc)}"

if ! command -v tesseract >/dev/null 2>&1; then
    SUDO=""
    if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
    $SUDO apt-get update
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y tesseract-ocr
fi
tesseract --version 2>&1 | head -1

VENV=benches/.venv
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
fi
"$VENV/bin/python" -c "import PIL, numpy" 2>/dev/null || "$VENV/bin/pip" install --quiet pillow numpy

cargo build --release

OUT="$(mktemp -d -t eyekey-calibration.XXXXXX)"
echo "views in $OUT"
SECONDS=0
./target/release/eyekey experiment calibrate --out "$OUT" --count "$COUNT" --seed "$SEED"
GEN=$SECONDS

"$VENV/bin/python" benches/calibrate_ocr.py "$OUT" \
    --out docs/legibility-ocr.md \
    --jobs "$JOBS" \
    --generate-seconds "$GEN" \
    --command "bash benches/calibrate_ocr.sh $COUNT $SEED"
echo "views and per-view OCR results (ocr.csv) kept in $OUT"
