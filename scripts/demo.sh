#!/usr/bin/env bash
# The first thing to run: set up the venv (scripts/bootstrap.sh; idempotent, ~1 s when warm), then
# the demo (rbc_registration/ros/demo.py): a synthetic RA-like robot cell is written as a bag,
# replayed into a live registration_node, all targets are corrected through ~/correct_targets,
# TRE uncorrected vs corrected and the rho decision are printed, and `rbc-registration evaluate`
# writes the report directory. The node is always stopped (also on Ctrl-C).
#
# Usage: scripts/demo.sh [--out DIR] [--rate R] [--seed S] [--timeout SECONDS]
#   --out DIR   report directory (default demo_out/ in the current directory)
# DDS stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, own ROS_DOMAIN_ID).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
for arg in "$@"; do
  case "$arg" in
    -h|--help) sed -n '2,10p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
  esac
done
START=$(date +%s)
bash "$ROOT/scripts/bootstrap.sh"
# shellcheck source=scripts/env.sh
source "$ROOT/scripts/env.sh"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
unset ROS_STATIC_PEERS
echo "demo: ROS_DOMAIN_ID=$ROS_DOMAIN_ID, discovery on localhost only"
status=0
"$RBC_VENV/bin/python" -m rbc_registration.ros.demo "$@" || status=$?
echo "demo: finished in $(( $(date +%s) - START )) s (exit $status)"
exit $status
