#!/usr/bin/env bash
# Installs Debian's Chromium for the browser tests of `craftext-llm view` (in tests/test_view.py),
# which drives it with Playwright. Idempotent: does nothing when a Chromium is already on PATH.
# Playwright's own browser download (`playwright install`) is never used: the test points
# Playwright at the system executable.
set -euo pipefail

for name in chromium chromium-browser; do
    if command -v "$name" >/dev/null 2>&1; then
        echo "chromium present: $(command -v "$name")"
        exit 0
    fi
done
if [ "$(id -u)" -ne 0 ]; then
    echo "chromium not found and not running as root: install it with 'sudo apt-get install chromium'" \
        "(the browser test skips without it)"
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "chromium not found and no apt-get: install a Chromium yourself (the browser test skips without it)"
    exit 0
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends chromium
echo "chromium installed: $(command -v chromium)"
