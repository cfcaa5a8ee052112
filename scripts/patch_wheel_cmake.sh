#!/usr/bin/env bash
# Make the cmake exports of the ROS 2 PyPI wheels usable in a venv:
#   scripts/patch_wheel_cmake.sh [VENV]        (default: $VIRTUAL_ENV, else <repo>/.venv)
# The wheels' *__rosidl_generator_pyExport.cmake files name the Python and numpy include dirs of
# the machine that built them (/opt/python/cp311-cp311/...); cmake refuses imported targets with
# missing include dirs, so building any interface package against them fails. This rewrites them
# to the venv's own dirs. Idempotent; rerun after (re)installing ROS message wheels.
set -euo pipefail
VENV="${1:-${VIRTUAL_ENV:-$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/.venv}}"
PY="$VENV/bin/python"
[ -x "$PY" ] || { echo "patch_wheel_cmake: no python in $VENV" >&2; exit 1; }
PY_INCLUDE="$(_ROS_WHEELS_BOOTSTRAP_COMPLETE=1 "$PY" -c \
  'import sysconfig; print(sysconfig.get_paths()["include"])')"
NUMPY_INCLUDE="$(_ROS_WHEELS_BOOTSTRAP_COMPLETE=1 "$PY" -c 'import numpy; print(numpy.get_include())')"
if [ ! -f "$PY_INCLUDE/Python.h" ]; then
  echo "patch_wheel_cmake: Python.h not in $PY_INCLUDE (Debian: apt-get install python3.11-dev)" >&2
  exit 1
fi
n=0
while IFS= read -r f; do
  sed -i \
    -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$NUMPY_INCLUDE#g" \
    -e "s#/opt/python/cp311-cp311/include/python3.11#$PY_INCLUDE#g" "$f"
  n=$((n + 1))
done < <(grep -rlF --include='*.cmake' '/opt/python/cp311-cp311' "$VENV/share" 2>/dev/null || true)
echo "patch_wheel_cmake: $n cmake file(s) patched in $VENV/share"
