#!/usr/bin/env bash
# Set up (or update) the development venv at <repo>/.venv, idempotently:
#   1. a Python 3.11 venv;
#   2. ROS 2 Kilted from PyPI wheels plus the project's and the tests' dependencies, pinned by
#      requirements.txt and constraints.txt;
#   3. the ROS interface packages not on PyPI, each built with cmake and installed INTO the venv
#      prefix (libraries in .venv/lib, Python modules in .venv/lib/python3.11/site-packages):
#      vendor/tf2_msgs (ros2/geometry2's tf2_msgs) and msg_docs/rbc_registration_interfaces;
#   4. `pip install -e .` of rbc_registration, with the install layout of a colcon install
#      mirrored as symlinks: share/rbc_registration (package.xml, launch/, config/), the ament
#      index marker, and the console scripts in lib/rbc_registration/ (setup.cfg's
#      install_scripts), where `ros2 run` and launch_ros look executables up.
# Each step is skipped while a stamp keyed on a hash of its inputs matches, so a second run takes
# about a second.
#
# How the generated typesupport libraries are found: the ROS wheels install
# ros_wheels_bootstrapper.pth, which re-executes every Python of the venv once (same PID) with
# LD_LIBRARY_PATH = <venv>/lib + site-packages/ros_*.libs. Installing the interface packages with
# CMAKE_INSTALL_PREFIX=<venv> puts their lib*.so in <venv>/lib, which is on that path.
#
# Usage: scripts/bootstrap.sh [--freeze]
#   --freeze  after setting up, rewrite constraints.txt from what is installed in the venv.
# Environment: RBC_VENV (default <repo>/.venv), RBC_PYTHON (default python3.11).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${RBC_VENV:-$ROOT/.venv}"
PYTHON="${RBC_PYTHON:-python3.11}"
STAMPS="$VENV/.rbc-stamps"
LOGS="$VENV/.rbc-logs"
FREEZE=0
for arg in "$@"; do
  case "$arg" in
    --freeze) FREEZE=1 ;;
    -h|--help) sed -n '2,23p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bootstrap: unknown argument: $arg" >&2; exit 2 ;;
  esac
done

say() { echo "bootstrap: $*"; }
die() { echo "bootstrap: ERROR: $*" >&2; exit 1; }
trap 'echo "bootstrap: ERROR: command failed (line $LINENO): $BASH_COMMAND" >&2' ERR

# A sourced ROS installation or another venv would mix its Python and libraries with ours.
if [ -n "${ROS_DISTRO:-}" ]; then
  say "note: ROS_DISTRO=$ROS_DISTRO is set; the venv ignores that installation"
fi
unset PYTHONPATH AMENT_PREFIX_PATH CMAKE_PREFIX_PATH COLCON_PREFIX_PATH _ROS_WHEELS_BOOTSTRAP_COMPLETE
export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_INPUT=1

# Run a command quietly; on failure show the end of its log.
run_logged() {
  local name="$1"; shift
  mkdir -p "$LOGS"
  if ! "$@" >"$LOGS/$name.log" 2>&1; then
    tail -n 40 "$LOGS/$name.log" >&2
    die "$name failed (full log: $LOGS/$name.log)"
  fi
}

hash_of() {  # hash_of TEXT FILE... -> sha256 of TEXT and the files' names and contents
  local text="$1"; shift
  { echo "$text"; for f in "$@"; do echo "== ${f#"$ROOT"/}"; cat "$f"; done; } | sha256sum | cut -d' ' -f1
}
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; echo "$2" >"$STAMPS/$1"; }

command -v "$PYTHON" >/dev/null 2>&1 || die "$PYTHON not found (install Python 3.11 with its venv module)"
PY_VERSION="$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
[ "$PY_VERSION" = "3.11" ] || die "$PYTHON is Python $PY_VERSION; the ROS wheels need 3.11"

# One bootstrap at a time per venv (engineers and CI may run tests concurrently in one tree).
mkdir -p "$(dirname "$VENV")"
exec 9>"$VENV.lock"
flock 9

VPY="$VENV/bin/python"
if [ ! -x "$VPY" ] || [ "$("$VPY" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)" != "3.11" ]; then
  say "creating venv $VENV"
  rm -rf "$VENV"
  "$PYTHON" -m venv "$VENV"
fi
export PATH="$VENV/bin:$PATH"

SELF_HASH="$(hash_of "python=$PY_VERSION venv=$VENV" "${BASH_SOURCE[0]}")"
DEPS_HASH="$(hash_of "$SELF_HASH" "$ROOT/requirements.txt" "$ROOT/constraints.txt")"
# The interface packages built with cmake (step 3), in build order, with the Python import that
# proves each one installed.
ROSIDL_PACKAGES=(tf2_msgs rbc_registration_interfaces)
declare -A ROSIDL_SRC=(
  [tf2_msgs]="$ROOT/vendor/tf2_msgs"
  [rbc_registration_interfaces]="$ROOT/msg_docs/rbc_registration_interfaces")
declare -A ROSIDL_CHECK=(
  [tf2_msgs]='from tf2_msgs.msg import TFMessage
from tf2_msgs.action import LookupTransform'
  [rbc_registration_interfaces]='from rbc_registration_interfaces.msg import FiducialPair
from rbc_registration_interfaces.srv import CorrectTarget')
rosidl_hash() {  # rosidl_hash NAME -> hash of the dependencies, the patch script and its files
  local src="${ROSIDL_SRC[$1]}" files=()
  files=("$src/CMakeLists.txt" "$src/package.xml")
  while IFS= read -r f; do files+=("$f"); done < <(
    find "$src/msg" "$src/srv" "$src/action" -type f \
      \( -name '*.msg' -o -name '*.srv' -o -name '*.action' \) 2>/dev/null | LC_ALL=C sort)
  hash_of "$DEPS_HASH $1" "$ROOT/scripts/patch_wheel_cmake.sh" "${files[@]}"
}
declare -A ROSIDL_HASH=()
for pkg in "${ROSIDL_PACKAGES[@]}"; do ROSIDL_HASH[$pkg]="$(rosidl_hash "$pkg")"; done
rosidl_stamps_ok() {
  local pkg
  for pkg in "${ROSIDL_PACKAGES[@]}"; do stamp_ok "rosidl-$pkg" "${ROSIDL_HASH[$pkg]}" || return 1; done
}
PROJECT_HASH="$(hash_of "$DEPS_HASH" "$ROOT/setup.py" "$ROOT/setup.cfg" "$ROOT/package.xml")"

check_imports() {
  local pkg
  for pkg in "${ROSIDL_PACKAGES[@]}"; do
    "$VPY" -c "${ROSIDL_CHECK[$pkg]}" >/dev/null 2>&1 || return 1
  done
  "$VPY" -c 'import rclpy, numpy, scipy, rosbags, yaml
import rbc_registration' >/dev/null 2>&1 && [ -x "$VENV/bin/rbc-registration" ]
}
# The console scripts of rbc_registration (setup.py's entry points) and whether each one is in
# <venv>/lib/rbc_registration/, as `ros2 run` / launch_ros look it up (<prefix>/lib/<package>/).
console_scripts() {
  "$VPY" -c 'import importlib.metadata as md
print("\n".join(sorted(e.name for e in md.distribution("rbc_registration").entry_points
                        if e.group == "console_scripts")))'
}
layout_ok() {
  local exe names
  names="$(console_scripts 2>/dev/null)" && [ -n "$names" ] || return 1
  for exe in $names; do [ -x "$VENV/lib/rbc_registration/$exe" ] || return 1; done
}

if stamp_ok deps "$DEPS_HASH" && rosidl_stamps_ok && stamp_ok project "$PROJECT_HASH" \
    && check_imports && layout_ok; then
  say "venv up to date ($VENV)"
  if [ "$FREEZE" = 0 ]; then exit 0; fi
elif stamp_ok deps "$DEPS_HASH" && rosidl_stamps_ok && stamp_ok project "$PROJECT_HASH" \
    && ! check_imports; then
  say "venv is stamped up to date but does not import: rebuilding the interfaces and the project"
  rm -f "$STAMPS"/rosidl-* "$STAMPS/project"
fi

# --- 2. Python packages ------------------------------------------------------------------------
if ! stamp_ok deps "$DEPS_HASH"; then
  say "installing ROS 2 wheels and Python dependencies (about 1 min)"; t0=$SECONDS
  # `pip install -e . --no-build-isolation` below needs setuptools >= 64 (PEP 660) in the venv.
  if ! "$VPY" -c 'import setuptools, sys; sys.exit(int(setuptools.__version__.split(".")[0]) < 64)' \
      >/dev/null 2>&1; then
    run_logged pip-setuptools "$VPY" -m pip install 'setuptools>=64,<81'
  fi
  run_logged pip-install "$VPY" -m pip install -r "$ROOT/requirements.txt" -c "$ROOT/constraints.txt"
  rm -f "$STAMPS"/rosidl-*  # reinstalled wheels bring back the unpatched cmake files
  stamp_set deps "$DEPS_HASH"
  say "  done in $((SECONDS - t0)) s"
fi

# --- 3. Interface packages --------------------------------------------------------------------
CMAKE_READY=0
prepare_cmake() {  # once per run: cmake, compilers, the wheels' cmake files patched
  [ "$CMAKE_READY" = 1 ] && return 0
  if ! command -v cmake >/dev/null 2>&1; then
    say "cmake not found: installing it from PyPI into the venv"
    run_logged pip-cmake "$VPY" -m pip install 'cmake>=3.22,<4'
  fi
  command -v c++ >/dev/null 2>&1 && command -v cc >/dev/null 2>&1 \
    || die "a C and C++ compiler is needed (Debian: apt-get install build-essential)"
  export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
  # The wheels' exported cmake targets name the include dirs of the machine that built them.
  run_logged patch-wheel-cmake bash "$ROOT/scripts/patch_wheel_cmake.sh" "$VENV"
  CMAKE_READY=1
}

build_rosidl_package() {  # build_rosidl_package NAME: configure, build, install into the venv
  local pkg="$1" src="${ROSIDL_SRC[$1]}" build="$VENV/build/$1" t0=$SECONDS
  say "building $pkg with cmake (about 30 s)"
  prepare_cmake
  if [ -f "$build/install_manifest.txt" ]; then  # remove what the previous build installed
    xargs -d '\n' rm -f <"$build/install_manifest.txt"
  fi
  rm -rf "$build" "$VENV/lib/python3.11/site-packages/$pkg"
  mkdir -p "$build"
  run_logged "cmake-configure-$pkg" cmake -S "$src" -B "$build" \
    -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_PREFIX_PATH="$VENV" \
    -DCMAKE_INSTALL_PREFIX="$VENV" \
    -DPython3_EXECUTABLE="$VPY" \
    -DPython3_FIND_VIRTUALENV=ONLY \
    -DBUILD_TESTING=OFF
  run_logged "cmake-build-$pkg" cmake --build "$build" --parallel "$(nproc)"
  run_logged "cmake-install-$pkg" cmake --install "$build"
  "$VPY" -c "${ROSIDL_CHECK[$pkg]}" || die "$pkg was built but does not import"
  stamp_set "rosidl-$pkg" "${ROSIDL_HASH[$pkg]}"
  say "  done in $((SECONDS - t0)) s"
}

rm -f "$STAMPS/interfaces"  # the stamp of the single interface package of earlier versions
for pkg in "${ROSIDL_PACKAGES[@]}"; do
  stamp_ok "rosidl-$pkg" "${ROSIDL_HASH[$pkg]}" || build_rosidl_package "$pkg"
done

# --- 4. The project, editable ------------------------------------------------------------------
if ! stamp_ok project "$PROJECT_HASH" || ! check_imports || ! layout_ok; then
  say "installing rbc_registration (pip install -e .)"
  # --use-pep517: an editable wheel (PEP 660), so the console scripts land in .venv/bin; the legacy
  # `setup.py develop` would follow setup.cfg and hide them in .venv/lib/rbc_registration.
  rm -rf "$VENV/lib/rbc_registration"
  run_logged pip-editable "$VPY" -m pip install --no-deps --no-build-isolation --use-pep517 \
    -e "$ROOT"
  # An editable install skips setup.py's data_files; mirror them as symlinks (like colcon's
  # --symlink-install) so ament_index finds package.xml, launch/ and config/ in the venv prefix.
  SHARE="$VENV/share/rbc_registration"
  mkdir -p "$SHARE" "$VENV/share/ament_index/resource_index/packages"
  for item in package.xml launch config; do ln -sfn "$ROOT/$item" "$SHARE/$item"; done
  : >"$VENV/share/ament_index/resource_index/packages/rbc_registration"
  # The editable wheel puts the console scripts in .venv/bin; `ros2 run` and launch_ros look for
  # them in <prefix>/lib/rbc_registration/ (setup.cfg's install_scripts): link them there.
  mkdir -p "$VENV/lib/rbc_registration"
  for exe in $(console_scripts); do
    ln -sfn "$VENV/bin/$exe" "$VENV/lib/rbc_registration/$exe"
  done
  check_imports || {
    for pkg in "${ROSIDL_PACKAGES[@]}"; do "$VPY" -c "${ROSIDL_CHECK[$pkg]}" || true; done
    "$VPY" -c 'import rclpy, numpy, scipy, rosbags, yaml
import rbc_registration' || true
    die "imports fail after set-up"
  }
  layout_ok || die "the console scripts are not all in $VENV/lib/rbc_registration after set-up"
  stamp_set project "$PROJECT_HASH"
fi

if [ "$FREEZE" = 1 ]; then
  say "writing constraints.txt"
  {
    echo "# Every distribution in .venv pinned to the version tested (transitive ones included)."
    echo "# Regenerate after changing requirements.txt: scripts/bootstrap.sh --freeze"
    "$VPY" - <<'EOF'
import importlib.metadata as md
pins = {}
for dist in md.distributions():
    name = dist.metadata['Name']
    # Only what pip installed: the ROS wheels also drop egg-info records (rclpy, std_msgs, ...)
    # that are not distributions on any index; the editable project is not pinned either.
    if (dist.read_text('INSTALLER') or '').strip() != 'pip' or dist.read_text('direct_url.json'):
        continue
    if name.lower() in ('pip', 'setuptools'):
        continue
    pins[name.lower()] = f'{name}=={dist.version}'
print('\n'.join(sorted(pins.values(), key=str.lower)))
EOF
  } >"$ROOT/constraints.txt.new"
  mv "$ROOT/constraints.txt.new" "$ROOT/constraints.txt"
  say "constraints.txt written; the next run reinstalls against it"
fi
say "ready: $VENV (source scripts/env.sh to use it)"
