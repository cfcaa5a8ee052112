#!/usr/bin/env bash
# Set up (or update) the Ubuntu 24.04 compatibility venv at <repo>/.venv-ubuntu2404, idempotently:
# numpy, scipy, matplotlib, rosbags, pyyaml, pytest and hypothesis (and their dependencies) pinned by
# constraints-ubuntu2404.txt to Ubuntu 24.04's versions, and this package installed from a copy
# of the source tree with `pip install --no-deps` (a real install, not editable). No ROS packages:
# the pure test suite runs in it (.ci/run). A stamp keyed on the pins, this script and every
# project file skips the work while nothing changed (about a second).
#
# Usage: scripts/compat_venv.sh        prints the venv's python on its last line
# Environment: RBC_COMPAT_VENV (default <repo>/.venv-ubuntu2404), RBC_PYTHON (default python3.11).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${RBC_COMPAT_VENV:-$ROOT/.venv-ubuntu2404}"
PYTHON="${RBC_PYTHON:-python3.11}"
PINS="$ROOT/constraints-ubuntu2404.txt"
PACKAGES=(numpy scipy matplotlib rosbags pyyaml pytest hypothesis)
STAMP="$VENV/.rbc-compat-stamp"
LOG="$VENV/.rbc-compat.log"

say() { echo "compat_venv: $*" >&2; }
die() { echo "compat_venv: ERROR: $*" >&2; exit 1; }
unset PYTHONPATH _ROS_WHEELS_BOOTSTRAP_COMPLETE
export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_INPUT=1

command -v "$PYTHON" >/dev/null 2>&1 || die "$PYTHON not found"
mkdir -p "$(dirname "$VENV")"
exec 9>"$VENV.lock"
flock 9

# The project's files as git sees them (tracked, and new files not ignored): what gets installed.
cd "$ROOT"
mapfile -t FILES < <(git ls-files --cached --others --exclude-standard | LC_ALL=C sort)
HASH="$({ echo "python=$PYTHON venv=$VENV"; cat "${BASH_SOURCE[0]}" "$PINS"
          for f in "${FILES[@]}"; do [ -f "$f" ] && { echo "== $f"; cat "$f"; }; done; } \
        | sha256sum | cut -d' ' -f1)"
VPY="$VENV/bin/python"
if [ -x "$VPY" ] && [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$HASH" ]; then
  say "up to date ($VENV)"
  echo "$VPY"
  exit 0
fi

if [ ! -x "$VPY" ]; then
  say "creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
rm -f "$STAMP"
say "installing ${PACKAGES[*]} pinned by $(basename "$PINS")"
"$VPY" -m pip install "${PACKAGES[@]}" -c "$PINS" >"$LOG" 2>&1 \
  || { tail -n 30 "$LOG" >&2; die "pip install failed (log: $LOG)"; }
# Build from a copy: an in-tree build/ could carry modules the source does not have.
SRC="$(mktemp -d)"
trap 'rm -rf "$SRC"' EXIT
for f in "${FILES[@]}"; do [ -f "$f" ] && install -D -m 644 "$f" "$SRC/$f"; done
say "installing rbc_registration (pip install --no-deps, not editable)"
"$VPY" -m pip uninstall -y rbc_registration >>"$LOG" 2>&1 || true
"$VPY" -m pip install --no-deps "$SRC" >>"$LOG" 2>&1 \
  || { tail -n 30 "$LOG" >&2; die "installing the project failed (log: $LOG)"; }
# pip puts the console scripts in bin/; `ros2 run` and launch_ros look for them in
# <prefix>/lib/rbc_registration/ (setup.cfg's install_scripts, as colcon installs them): link them.
rm -rf "$VENV/lib/rbc_registration"
mkdir -p "$VENV/lib/rbc_registration"
for exe in $("$VPY" -c 'import importlib.metadata as md
print("\n".join(sorted(e.name for e in md.distribution("rbc_registration").entry_points
                        if e.group == "console_scripts")))'); do
  ln -sfn "$VENV/bin/$exe" "$VENV/lib/rbc_registration/$exe"
done
(cd "$VENV" && "$VPY" - "$PINS" <<'EOF') || die "the venv does not hold the pinned versions and an installed rbc_registration"
import importlib.metadata as md, re, sys
pins = dict(re.match(r"([A-Za-z0-9_.-]+)==(\S+)", line).groups()
            for line in open(sys.argv[1]) if re.match(r"[A-Za-z0-9_.-]+==", line))
bad = {n: (v, md.version(n)) for n, v in pins.items() if md.version(n) != v}
import rbc_registration
assert "site-packages" in rbc_registration.__file__, rbc_registration.__file__
if bad:
    sys.exit(f"installed versions differ from the pins: {bad}")
EOF
echo "$HASH" >"$STAMP"
say "ready: $VENV"
echo "$VPY"
