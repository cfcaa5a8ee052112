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
exec "$RBC_VENV/bin/python" -m pytest test "$@"
