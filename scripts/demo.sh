#!/usr/bin/env bash
# Demo: sets up the workspace, brings the node graph up, runs the task end to end, writes a report.
# Usage: scripts/demo.sh [--scenario NAME|PATH] [--out DIR] [--record [DIR]] [demo.py args]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

scenario="clean"
out="${OUT:-out/demo}"
extra=()
while (($#)); do
  case "$1" in
    --scenario) [[ $# -ge 2 ]] || { echo "demo: --scenario needs a value" >&2; exit 2; }
      scenario="$2"; shift 2 ;;
    --scenario=*) scenario="${1#*=}"; shift ;;
    --out) [[ $# -ge 2 ]] || { echo "demo: --out needs a value" >&2; exit 2; }
      out="$2"; shift 2 ;;
    --out=*) out="${1#*=}"; shift ;;
    -h|--help) sed -n '2,3s/^# \{0,1\}//p' "$0"; exit 0 ;;
    *) extra+=("$1"); shift ;;
  esac
done

TSRRT_SETUP_QUIET=1 bash "$ROOT/scripts/setup.sh"
# shellcheck source=scripts/env.sh
source "$ROOT/scripts/env.sh"
# A DDS domain of its own unless the caller chose one, so that a demo never sees the nodes of a
# test run (tests take 1..101) or, most likely, of another demo; inspect it with the printed id.
# 215..232 are the other domain ids whose UDP ports are valid on Linux.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((RANDOM % 18 + 215))}"
echo "[demo] ROS_DOMAIN_ID=$ROS_DOMAIN_ID"
# Relative paths are taken from the caller's directory, as the user typed them.
exec python "$ROOT/scripts/demo.py" --scenario "$scenario" --out "$out" ${extra[@]+"${extra[@]}"}
