#!/usr/bin/env bash
# Installs the TrueType fonts the judges are tested and calibrated on (src/research/fonts.rs), when they are
# missing: Debian's fonts-dejavu-core and fonts-liberation2. Needs root (CI runs as root); prints what it did.
set -euo pipefail
want=(/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf /usr/share/fonts/truetype/liberation2/LiberationMono-Regular.ttf)
missing=0
for f in "${want[@]}"; do [ -f "$f" ] || missing=1; done
if [ "$missing" = 0 ]; then
    echo "fonts present: DejaVu, Liberation"
    exit 0
fi
if [ "$(id -u)" != 0 ]; then
    echo "fonts are missing; run as root: apt-get install fonts-dejavu-core fonts-liberation2" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends fonts-dejavu-core fonts-liberation2 >/dev/null
echo "installed fonts-dejavu-core and fonts-liberation2"
