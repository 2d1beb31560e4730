#!/usr/bin/env bash
# The paper's four experiments end to end, tabulated beside its Fig. 9/10.
# Usage: scripts/reproduce_paper.sh [--out DIR] [--budget-s S] [--seeds N]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
TSRRT_SETUP_QUIET=1 bash "$ROOT/scripts/setup.sh"
# shellcheck source=scripts/env.sh
source "$ROOT/scripts/env.sh"
# A DDS domain apart from test runs (1..101), as demo.sh does.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((RANDOM % 18 + 215))}"
# SLSQP in the planner is ~10x slower with multi-threaded OpenBLAS on small problems.
export OPENBLAS_NUM_THREADS=1
exec python "$ROOT/scripts/reproduce_paper.py" "$@"
