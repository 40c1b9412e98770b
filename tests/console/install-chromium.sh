#!/usr/bin/env bash
# Installs Debian's Chromium and ChromeDriver for the console's browser test, when they are missing.
# Needs root (CI runs as root); prints what it did.
set -euo pipefail
if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then
    echo "chromium and chromedriver present: $(chromedriver --version)"
    exit 0
fi
if [ "$(id -u)" != 0 ]; then
    echo "chromium and chromedriver are missing; run as root: apt-get install chromium chromium-driver" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends chromium chromium-driver fonts-dejavu-core >/dev/null
echo "installed $(chromedriver --version)"
