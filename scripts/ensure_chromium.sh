#!/usr/bin/env bash
# Makes sure Debian's Chromium is at /usr/bin/chromium for the browser tests (Playwright drives it; no
# browser is ever downloaded by Playwright itself). Does nothing when it is already there.
set -euo pipefail
if [ -x /usr/bin/chromium ]; then
  exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
  sudo_cmd="sudo"
  command -v sudo >/dev/null 2>&1 || { echo "ensure_chromium: need root (or sudo) to apt-get install chromium" >&2; exit 0; }
else
  sudo_cmd=""
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "ensure_chromium: no apt-get here; the browser tests will skip (install Chromium at /usr/bin/chromium)" >&2
  exit 0
fi
export DEBIAN_FRONTEND=noninteractive
$sudo_cmd apt-get update -qq
$sudo_cmd apt-get install -y -qq chromium >/dev/null
echo "ensure_chromium: installed $(/usr/bin/chromium --version 2>/dev/null | head -1)"
