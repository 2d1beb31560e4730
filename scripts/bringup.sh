#!/usr/bin/env bash
# Start the tsrrt node graph: sim, perception, executor and planner, each with its YAML parameters.
# Usage: scripts/bringup.sh [--scenario NAME|PATH] [--seed N] [--models FILE] [--log-dir DIR]
# Runs until interrupted (Ctrl-C / SIGTERM), then stops every node it started.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

scenario="clean"
seed="-1"
log_dir=""
models=""
while (($#)); do
  case "$1" in
    --scenario) scenario="${2:?--scenario needs a value}"; shift 2 ;;
    --scenario=*) scenario="${1#*=}"; shift ;;
    --seed) seed="${2:?--seed needs a value}"; shift 2 ;;
    --seed=*) seed="${1#*=}"; shift ;;
    --models) models="${2:?--models needs a value}"; shift 2 ;;
    --models=*) models="${1#*=}"; shift ;;
    --log-dir) log_dir="${2:?--log-dir needs a value}"; shift 2 ;;
    --log-dir=*) log_dir="${1#*=}"; shift ;;
    -h|--help) sed -n '2,4s/^# \{0,1\}//p' "$0"; exit 0 ;;
    *) echo "bringup: unknown argument $1" >&2; exit 2 ;;
  esac
done
# A scenario given as a relative path is taken from the caller's directory.
absolute() { echo "$(cd "$(dirname "$1")" && pwd)/$(basename "$1")"; }
if [[ -f "$scenario" ]]; then scenario="$(absolute "$scenario")"; fi
if [[ -n "$models" ]]; then mkdir -p "$(dirname "$models")"; models="$(absolute "$models")"; fi

TSRRT_SETUP_QUIET=1 bash "$ROOT/scripts/setup.sh"
# shellcheck source=scripts/env.sh
source "$ROOT/scripts/env.sh"

# Four nodes share this machine's cores: one BLAS thread each (the planner's SLSQP is also ~10x
# faster single-threaded on its small problems).
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
install="$ROOT/ros2_ws/install"
pids=()
# Nodes get SIGTERM: a non-interactive shell starts background jobs with SIGINT ignored.
stop() {
  trap - INT TERM EXIT
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
  done
}
trap stop INT TERM EXIT

start() {  # package node extra-parameters...
  local package="$1" node="$2"; shift 2
  local command=("$install/$package/lib/$package/$node" --ros-args
                 --params-file "$install/$package/share/$package/config/$node.yaml" "$@")
  if [[ -n "$log_dir" ]]; then
    mkdir -p "$log_dir"
    "${command[@]}" >"$log_dir/$node.log" 2>&1 &
  else
    "${command[@]}" &
  fi
  pids+=("$!")
}

start tsrrt_sim sim_node -p "scenario:=$scenario" -p "seed:=$seed"
start tsrrt_perception perception_node -p "scenario:=$scenario" -p "scenario_seed:=$seed"
start tsrrt_executor executor_node
planner_args=(-p "scenario:=$scenario" -p "seed:=$seed")
if [[ -n "$models" ]]; then planner_args+=(-p "models_path:=$models"); fi
start tsrrt_planner planner_node "${planner_args[@]}"
echo "[bringup] scenario $scenario: sim, perception, executor and planner running" \
  "(ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-0}); Ctrl-C stops them" >&2
wait -n "${pids[@]}" || true
echo "[bringup] a node exited; stopping the others" >&2
