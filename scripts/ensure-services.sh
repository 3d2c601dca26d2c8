#!/usr/bin/env bash
# Make sure the services the test suite talks to for real are up before pytest starts:
#   PostgreSQL on 127.0.0.1:5432 (URL $RGSE_TEST_PG_URL, default postgresql://postgres@127.0.0.1:5432/test)
#   Mosquitto  on 127.0.0.1:1883
# Already up: returns at once (well under 2 s). Down: starts them; not installed and we are root with apt-get:
# installs them (and, on a fresh PostgreSQL, trusts loopback logins and creates the test database). Still down:
# exits 1 with a message saying what is missing. Tests never skip for lack of a service.
#
# Usage: scripts/ensure-services.sh [--check]
#   --check   only look, never start or install anything (exit 1 if a service is down)
# Environment: RGSE_TEST_PG_URL, RGSE_TEST_PG_PORT (5432), RGSE_TEST_MQTT_PORT (1883).
set -uo pipefail

CHECK_ONLY=0
case "${1:-}" in
    "") ;;
    --check) CHECK_ONLY=1 ;;
    *) echo "usage: $0 [--check]" >&2; exit 2 ;;
esac

PG_HOST=127.0.0.1
PG_PORT="${RGSE_TEST_PG_PORT:-5432}"
MQTT_HOST=127.0.0.1
MQTT_PORT="${RGSE_TEST_MQTT_PORT:-1883}"
PG_URL="${RGSE_TEST_PG_URL:-postgresql://postgres@127.0.0.1:5432/test}"
WAIT_S=20

say() { echo "ensure-services: $*" >&2; }

port_open() {  # host port -> 0 if something accepts a TCP connection within 1 s
    timeout 1 bash -c "exec 3<>/dev/tcp/$1/$2" 2>/dev/null
}

wait_port() {  # host port seconds
    local i
    for ((i = 0; i < $3 * 5; i++)); do
        port_open "$1" "$2" && return 0
        sleep 0.2
    done
    return 1
}

pg_login_ok() {  # a real login to the test database; TCP alone is not enough (auth, missing database)
    command -v psql >/dev/null 2>&1 || return 0  # no client here: the tests' own connection will tell
    PGCONNECT_TIMEOUT=2 psql "$PG_URL" -Atqc 'SELECT 1' >/dev/null 2>&1
}

is_root() { [ "$(id -u)" = 0 ]; }

apt_install() {  # packages...
    if ! is_root || ! command -v apt-get >/dev/null 2>&1; then
        say "cannot install $* (need root and apt-get)"
        return 1
    fi
    say "installing $* with apt-get"
    if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@"; } >/dev/null; then
        say "apt-get install $* failed"
        return 1
    fi
}

as_postgres() {  # run a command as the postgres OS user (peer authentication on the local socket)
    if command -v runuser >/dev/null 2>&1; then runuser -u postgres -- "$@"; else su postgres -s /bin/sh -c "$*"; fi
}

start_postgres() {
    local version
    if [ ! -d /etc/postgresql ] || ! command -v pg_ctlcluster >/dev/null 2>&1; then
        apt_install postgresql || return 1
    fi
    for version in $(ls /etc/postgresql 2>/dev/null); do
        [ -d "/etc/postgresql/$version/main" ] || continue
        say "starting PostgreSQL $version/main"
        # Its exit status does not matter ("already running" is fine): the port decides.
        pg_ctlcluster --skip-systemctl-redirect "$version" main start >/dev/null 2>&1
    done
    wait_port "$PG_HOST" "$PG_PORT" "$WAIT_S"
}

configure_postgres() {  # only on a local cluster we may administer: loopback trust + the test database
    is_root && [ -d /etc/postgresql ] || return 1
    local hba db
    db="${PG_URL##*/}"
    db="${db%%\?*}"
    for hba in /etc/postgresql/*/main/pg_hba.conf; do
        [ -f "$hba" ] || continue
        if ! grep -Eq '^host[[:space:]]+all[[:space:]]+all[[:space:]]+127\.0\.0\.1/32[[:space:]]+trust' "$hba"; then
            say "trusting loopback logins in $hba (test machine)"
            sed -i '1i host all all 127.0.0.1/32 trust' "$hba"
        fi
    done
    as_postgres psql -qc 'SELECT pg_reload_conf()' >/dev/null 2>&1
    sleep 0.5
    if [ -n "$db" ] && ! as_postgres psql -Atqc "SELECT 1 FROM pg_database WHERE datname = '$db'" | grep -q 1; then
        say "creating database $db"
        as_postgres createdb "$db" >/dev/null 2>&1
    fi
    pg_login_ok
}

start_mosquitto() {
    if ! command -v mosquitto >/dev/null 2>&1 && [ ! -x /usr/sbin/mosquitto ]; then
        apt_install mosquitto || return 1
    fi
    local bin
    bin="$(command -v mosquitto || echo /usr/sbin/mosquitto)"
    if id mosquitto >/dev/null 2>&1 && is_root; then
        mkdir -p /run/mosquitto /var/log/mosquitto
        chown mosquitto: /run/mosquitto /var/log/mosquitto
    fi
    say "starting Mosquitto"
    if [ "$MQTT_PORT" = 1883 ] && [ -f /etc/mosquitto/mosquitto.conf ]; then  # the system config listens on 1883
        "$bin" -d -c /etc/mosquitto/mosquitto.conf >/dev/null 2>&1
        wait_port "$MQTT_HOST" "$MQTT_PORT" 5 && return 0
    fi
    "$bin" -d -p "$MQTT_PORT" >/dev/null 2>&1
    wait_port "$MQTT_HOST" "$MQTT_PORT" 5
}

# --- fast path -----------------------------------------------------------------------------------------------
pg_ok=1
mqtt_ok=1
port_open "$PG_HOST" "$PG_PORT" && pg_login_ok && pg_ok=0
port_open "$MQTT_HOST" "$MQTT_PORT" && mqtt_ok=0
[ "$pg_ok" = 0 ] && [ "$mqtt_ok" = 0 ] && exit 0

# --- repair --------------------------------------------------------------------------------------------------
if [ "$CHECK_ONLY" = 1 ]; then
    :
elif [ "$pg_ok" != 0 ]; then
    port_open "$PG_HOST" "$PG_PORT" || start_postgres
    if port_open "$PG_HOST" "$PG_PORT"; then
        pg_login_ok || configure_postgres
        pg_login_ok && pg_ok=0
    fi
fi
if [ "$CHECK_ONLY" = 0 ] && [ "$mqtt_ok" != 0 ]; then
    start_mosquitto && mqtt_ok=0
fi

status=0
if [ "$pg_ok" != 0 ]; then
    say "FAILED: PostgreSQL is not usable at $PG_URL (port $PG_HOST:$PG_PORT or login/database)."
    say "  Start it (pg_ctlcluster <version> main start) or install it (apt-get install postgresql) and re-run."
    status=1
fi
if [ "$mqtt_ok" != 0 ]; then
    say "FAILED: Mosquitto is not accepting connections on $MQTT_HOST:$MQTT_PORT."
    say "  Start it (mosquitto -d -p $MQTT_PORT) or install it (apt-get install mosquitto) and re-run."
    status=1
fi
[ "$status" = 0 ] && say "PostgreSQL and Mosquitto are up"
exit "$status"
