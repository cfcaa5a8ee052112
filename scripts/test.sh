#!/usr/bin/env bash
# Set up the venv if needed (scripts/bootstrap.sh), then run the test suite in it:
#   scripts/test.sh [pytest arguments...]      e.g. scripts/test.sh -k infra -x
# Exits with pytest's status.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/bootstrap.sh"
# shellcheck source=scripts/env.sh
source "$ROOT/scripts/env.sh"
cd "$ROOT"
# test/conftest.py also sets these, per process; here they cover anything started before it.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# Run the whole suite unless test paths are given (e.g. scripts/test.sh test/core -q).
for arg in "$@"; do
  case "$arg" in -*) ;; *) [ -e "$arg" ] || [ -e "${arg%%::*}" ] && exec "$RBC_VENV/bin/python" -m pytest "$@" ;; esac
done
exec "$RBC_VENV/bin/python" -m pytest test "$@"
