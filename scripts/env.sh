# shellcheck shell=bash
# Source me (bash): `source scripts/env.sh`. Activates .venv and the ros2_ws overlay.
# Never exits or changes the options of the calling shell; returns non-zero on failure.
# Run scripts/setup.sh first (it creates .venv and builds ros2_ws).

if [[ "${BASH_SOURCE[0]}" == "$0" ]]; then
  echo "scripts/env.sh must be sourced: source scripts/env.sh" >&2
  exit 2
fi

_tsrrt_env() {
  local root venv sp libs d
  root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)" || return 1
  venv="$root/.venv"
  if [[ ! -x "$venv/bin/python" || ! -f "$root/ros2_ws/install/setup.bash" ]]; then
    echo "[env] $root is not set up; run: bash scripts/setup.sh" >&2
    return 1
  fi

  # shellcheck disable=SC1091
  source "$venv/bin/activate" || return 1

  # The ROS 2 wheels install their ament packages under the venv prefix (.venv/share/<pkg>);
  # the venv has no local_setup.* for colcon to chain, so add it to the search paths here.
  case ":${AMENT_PREFIX_PATH:-}:" in *":$venv:"*) ;; *)
    export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" ;; esac
  case ":${CMAKE_PREFIX_PATH:-}:" in *":$venv:"*) ;; *)
    export CMAKE_PREFIX_PATH="$venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}" ;; esac

  # The wheels' ros_wheels_bootstrapper (.pth) re-execs every python with these library dirs
  # on LD_LIBRARY_PATH; setting them once here, plus its guard, skips that re-exec.
  sp="$venv/lib/python3.11/site-packages"
  libs="$venv/lib"
  for d in "$sp"/ros_*.libs; do [[ -d "$d" ]] && libs="$libs:$d"; done
  case ":${LD_LIBRARY_PATH:-}:" in *":$venv/lib:"*) ;; *)
    export LD_LIBRARY_PATH="$libs${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" ;; esac
  export _ROS_WHEELS_BOOTSTRAP_COMPLETE=1

  # shellcheck disable=SC1091
  source "$root/ros2_ws/install/setup.bash" || return 1

  export RMW_IMPLEMENTATION=rmw_fastrtps_cpp  # the only RMW the venv has
  # Keep DDS traffic on this machine unless the caller chose otherwise.
  export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
  # ROS_DOMAIN_ID: left as the caller set it (tests pick their own).
  export TSRRT_ROOT="$root"
}

# colcon's setup.bash and venv's activate are not `set -u`/`set -e` clean: relax those two
# options while they run, then restore what the caller had. ($- not $(set +o): a command
# substitution would report errexit as off.)
_tsrrt_saved_opts="$-"
set +eu
_tsrrt_env
_tsrrt_rc=$?
[[ "$_tsrrt_saved_opts" == *e* ]] && set -e
[[ "$_tsrrt_saved_opts" == *u* ]] && set -u
unset -f _tsrrt_env
unset _tsrrt_saved_opts
# The status of the last command is the status of `source`.
test "$_tsrrt_rc" -eq 0
