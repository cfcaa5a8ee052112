# Source this file (bash or zsh) to use the project's venv with the same environment as the tests:
#   source scripts/env.sh
# It does not create the venv: run scripts/bootstrap.sh first (scripts/test.sh does both).
#
# - PATH/VIRTUAL_ENV: the venv at <repo>/.venv (or $RBC_VENV).
# - AMENT_PREFIX_PATH: the venv prefix, which holds the ament index of the ROS wheels,
#   rbc_registration_interfaces and rbc_registration (for ament_index_python look-ups such as
#   get_package_share_directory('rbc_registration')). A pip venv does not set it by itself.
# - DDS stays on this machine: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and no static peers.
# - ROS_DOMAIN_ID: kept if you set it, else one derived from this shell's PID (1..101), so two
#   shells running nodes or tests at once do not see each other; the value chosen is recorded in
#   RBC_CHOSEN_ROS_DOMAIN_ID, so that a ROS_DOMAIN_ID equal to it is not taken for yours (a second
#   source, scripts/test.sh, test/conftest.py choose their own per process).
if [ -n "${BASH_SOURCE:-}" ]; then
  _rbc_here="${BASH_SOURCE[0]}"
elif [ -n "${ZSH_VERSION:-}" ]; then
  _rbc_here="${(%):-%x}"
else
  _rbc_here="$0"
fi
_rbc_root="$(cd "$(dirname "$_rbc_here")/.." && pwd)"
export RBC_VENV="${RBC_VENV:-$_rbc_root/.venv}"
if [ ! -x "$RBC_VENV/bin/python" ]; then
  echo "env.sh: no venv at $RBC_VENV; run scripts/bootstrap.sh first" >&2
fi
export VIRTUAL_ENV="$RBC_VENV"
case ":$PATH:" in
  *":$RBC_VENV/bin:"*) ;;
  *) export PATH="$RBC_VENV/bin:$PATH" ;;
esac
export AMENT_PREFIX_PATH="$RBC_VENV"
# Let the wheels' bootstrapper compute LD_LIBRARY_PATH for this venv on the next Python start.
unset _ROS_WHEELS_BOOTSTRAP_COMPLETE PYTHONPATH
export RMW_IMPLEMENTATION=rmw_fastrtps_cpp
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
unset ROS_STATIC_PEERS ROS_LOCALHOST_ONLY
if [ -z "${ROS_DOMAIN_ID:-}" ] || [ "$ROS_DOMAIN_ID" = "${RBC_CHOSEN_ROS_DOMAIN_ID:-}" ]; then
  export ROS_DOMAIN_ID="$(( $$ % 101 + 1 ))" RBC_CHOSEN_ROS_DOMAIN_ID="$(( $$ % 101 + 1 ))"
fi
export ROS_DOMAIN_ID
unset _rbc_here _rbc_root
