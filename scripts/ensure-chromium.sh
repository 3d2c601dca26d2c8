#!/bin/sh
# Make sure a headless-capable Chromium is installed; print the path of its binary on stdout (and nothing else).
#
# Used by tests/report (the HTML report is checked in a real browser) and by CI. Installs Debian's `chromium`
# package with apt-get when no browser is found (needs root or passwordless sudo); runs `apt-get update` once
# first. Exits non-zero with a message on stderr when that is impossible: the caller must fail, never skip.
set -eu

find_browser() {
    for name in chromium chromium-browser google-chrome-stable google-chrome; do
        if path=$(command -v "$name" 2>/dev/null); then
            printf '%s\n' "$path"
            return 0
        fi
    done
    return 1
}

if find_browser; then
    exit 0
fi

if [ "$(id -u)" -eq 0 ]; then
    SUDO=""
elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    SUDO="sudo -n"
else
    echo "ensure-chromium: no chromium found and not root (no passwordless sudo): install Debian's 'chromium'" >&2
    exit 1
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "ensure-chromium: no chromium found and no apt-get to install it with" >&2
    exit 1
fi

# One installer at a time (parallel test runs): flock on a lock file when available.
LOCK=/tmp/rgse-ensure-chromium.lock
install_it() {
    if find_browser >/dev/null; then
        return 0
    fi
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get update -q >&2 || { echo "ensure-chromium: apt-get update failed" >&2; return 1; }
    $SUDO apt-get install -y -q --no-install-recommends chromium >&2 \
        || { echo "ensure-chromium: apt-get install chromium failed" >&2; return 1; }
}
if command -v flock >/dev/null 2>&1; then
    exec 9>"$LOCK"
    flock 9
fi
install_it

if find_browser; then
    exit 0
fi
echo "ensure-chromium: chromium was installed but no binary is on PATH" >&2
exit 1
