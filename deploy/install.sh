#!/usr/bin/env bash
# Install the RGSE daemon as a systemd service on the measurement PC (Debian/Ubuntu, run as root):
#   sudo deploy/install.sh            # from a checkout of the project
# Creates the user 'rgse', copies the project to /opt/rgse with its own virtual environment, installs the unit and
# an example config to /etc/rgse/rgse.toml (kept if present), and enables the service. Idempotent.
set -euo pipefail

PREFIX=/opt/rgse
CONF_DIR=/etc/rgse
DATA_DIR=/var/lib/rgse
SRC="$(cd "$(dirname "$0")/.." && pwd)"

[ "$(id -u)" = 0 ] || { echo "install.sh: run as root" >&2; exit 1; }
command -v python3 >/dev/null || { echo "install.sh: python3 (>= 3.11) is needed" >&2; exit 1; }
python3 -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo "install.sh: python3 >= 3.11 needed" >&2; exit 1; }

id rgse >/dev/null 2>&1 || useradd --system --home-dir "$DATA_DIR" --shell /usr/sbin/nologin --user-group rgse
getent group dialout >/dev/null && usermod -aG dialout rgse

mkdir -p "$PREFIX" "$CONF_DIR" "$DATA_DIR"
# Copy the project (not its venv or caches) and install it into its own venv.
tar -C "$SRC" --exclude=.venv --exclude=.git --exclude='__pycache__' --exclude=data -cf - . | tar -C "$PREFIX" -xf -
python3 -m venv "$PREFIX/.venv"
"$PREFIX/.venv/bin/python" -m pip install --quiet --upgrade pip
"$PREFIX/.venv/bin/python" -m pip install --quiet -e "$PREFIX"

if [ ! -f "$CONF_DIR/rgse.toml" ]; then
    sed "s#^data_dir = .*#data_dir = \"$DATA_DIR\"#" "$PREFIX/deploy/rgse.example.toml" > "$CONF_DIR/rgse.toml"
    echo "install.sh: wrote $CONF_DIR/rgse.toml — set [controller] host before starting"
fi
chown -R rgse:rgse "$DATA_DIR"
chmod 0750 "$DATA_DIR"

# Validate the configuration before the service is enabled (bounds are checked without network I/O).
"$PREFIX/.venv/bin/python" -c "import sys; from rgse_daemon.config import load_config; load_config(sys.argv[1])" \
    "$CONF_DIR/rgse.toml"

install -m 0644 "$PREFIX/deploy/rgse-daemon.service" /etc/systemd/system/rgse-daemon.service
install -m 0644 "$PREFIX/deploy/mnt-krc4.mount" /etc/systemd/system/mnt-krc4.mount
if command -v systemd-analyze >/dev/null; then systemd-analyze verify /etc/systemd/system/rgse-daemon.service; fi
systemctl daemon-reload
systemctl enable rgse-daemon.service
echo "install.sh: installed. Start with: systemctl start rgse-daemon; logs: journalctl -u rgse-daemon -f"
