#!/usr/bin/env bash
# Installs the Debian/Raspberry Pi OS packages the project needs, only when missing:
#  - python3-venv: `python3 -m venv` (Debian splits ensurepip out of python3);
#  - systemd: systemd-analyze, which the tests use to verify the unit file;
#  - chromium, chromium-driver: the headless browser the rescue-hq console tests
#    drive (tests/test_hq_web_browser.py); no browser is downloaded from elsewhere;
#  - libimage-exiftool-perl: exiftool, which reads FLIR radiometric JPEGs' raw counts
#    and Planck constants (companion/sources/flir.py, `rescue-companion detect`).
# Needs root (or sudo) only when something is actually missing.
set -euo pipefail
missing=()
if ! python3 -c 'import ensurepip, venv' >/dev/null 2>&1; then
    missing+=(python3-venv)
fi
if ! command -v systemd-analyze >/dev/null 2>&1; then
    missing+=(systemd)
fi
if ! command -v chromium >/dev/null 2>&1; then
    missing+=(chromium)
fi
if ! command -v chromedriver >/dev/null 2>&1; then
    missing+=(chromium-driver)
fi
if ! command -v exiftool >/dev/null 2>&1; then
    missing+=(libimage-exiftool-perl)
fi
if [ ${#missing[@]} -eq 0 ]; then
    exit 0
fi
echo "installing system packages: ${missing[*]}"
if [ "$(id -u)" -ne 0 ]; then
    SUDO=sudo
else
    SUDO=
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "error: missing ${missing[*]} and no apt-get here; install them by hand" >&2
    exit 1
fi
$SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
