#!/usr/bin/env bash
# Makes sure Debian's PostgreSQL server binaries (initdb, pg_ctl) are here for the fleet tests, which
# start a private cluster of their own in a temporary folder on a free loopback port
# (tests/fleet/pg_cluster.py) and run the durability, restart and load tests on it as well as on
# SQLite. Does nothing when the binaries are already there; never starts or changes a system cluster.
set -euo pipefail
if ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || command -v initdb >/dev/null 2>&1; then
  exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
  sudo_cmd="sudo"
  command -v sudo >/dev/null 2>&1 || { echo "ensure_postgres: need root (or sudo) to apt-get install postgresql; the PostgreSQL tests will skip" >&2; exit 0; }
else
  sudo_cmd=""
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "ensure_postgres: no apt-get here; the PostgreSQL tests will skip (install PostgreSQL's initdb and pg_ctl)" >&2
  exit 0
fi
export DEBIAN_FRONTEND=noninteractive
$sudo_cmd apt-get update -qq
# Debian's postgresql package creates and starts a system cluster; the tests do not use it.
$sudo_cmd apt-get install -y -qq postgresql >/dev/null
echo "ensure_postgres: installed $(ls -d /usr/lib/postgresql/*/bin | tail -1)"
