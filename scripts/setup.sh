#!/usr/bin/env bash
# Idempotent workspace setup: .venv (Python 3.11) with the pinned requirements, a fix for a
# quirk of the ROS 2 PyPI wheels, then `colcon build` of ros2_ws. Fast when nothing changed:
# pip is keyed on the hash of requirements.txt, colcon on a hash of the package sources.
#
# Env knobs: TSRRT_SETUP_QUIET=1 (print nothing when everything is already up to date),
#            TSRRT_FORCE_BUILD=1 (run colcon even if the sources look unchanged),
#            PYTHON=/path/to/python3.11 (interpreter used to create .venv).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
WS="$ROOT/ros2_ws"
REQ_STAMP="$VENV/.tsrrt-requirements.sha256"
BUILD_STAMP="$WS/install/.tsrrt-build.sha256"
QUIET="${TSRRT_SETUP_QUIET:-0}"

log() { echo "[setup] $*" >&2; }
die() { echo "[setup] ERROR: $*" >&2; exit 1; }

is_py311() { "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; }

# The ROS 2 Jazzy wheels are cp311 only, so the venv must be Python 3.11.
find_python() {
  local cand
  local pyenv="${PYENV_ROOT:-${HOME:-/root}/.pyenv}"
  for cand in "${PYTHON:-}" python3.11 python3 "$pyenv"/versions/3.11*/bin/python3.11 \
      /usr/bin/python3.11; do
    [[ -n "$cand" ]] || continue
    if command -v "$cand" >/dev/null 2>&1 && is_py311 "$cand"; then
      command -v "$cand"
      return 0
    fi
  done
  return 1
}

# Several shells (engineers, test runs) may share this tree: one setup at a time, the others
# wait and then find everything up to date.
mkdir -p "$WS/log"
if command -v flock >/dev/null 2>&1; then
  exec 9>"$WS/log/.tsrrt-setup.lock"
  flock 9
fi

# --- 1. virtualenv ---------------------------------------------------------------------------
if [[ -e "$VENV" ]] && ! is_py311 "$VENV/bin/python"; then
  # A venv whose interpreter is gone or is not 3.11 cannot load the wheels: start over.
  log "existing .venv is broken or not Python 3.11; recreating it"
  rm -rf "$VENV"
fi
if [[ ! -x "$VENV/bin/python" ]]; then
  PY="$(find_python)" || die "Python 3.11 not found (tried \$PYTHON, python3.11, python3," \
    "pyenv, /usr/bin/python3.11); install it or set PYTHON=/path/to/python3.11"
  log "creating .venv with $PY ($("$PY" --version 2>&1))"
  "$PY" -m venv "$VENV" || die "'$PY -m venv' failed (on Debian: apt-get install python3.11-venv)"
fi
VPY="$VENV/bin/python"

# --- 2. pinned requirements ------------------------------------------------------------------
req_hash="$(sha256sum "$ROOT/requirements.txt" | cut -d' ' -f1)"
if [[ "$(cat "$REQ_STAMP" 2>/dev/null || true)" != "$req_hash" ]]; then
  log "installing requirements.txt into .venv (takes a minute or two on a fresh venv)"
  # Output to a file, shown only on failure (pip's per-index warnings are noise otherwise).
  pip_log="$VENV/.tsrrt-pip-install.txt"
  if ! "$VPY" -m pip install --disable-pip-version-check --no-input -r "$ROOT/requirements.txt" \
      >"$pip_log" 2>&1; then
    grep -v 'is ignored: it is neither a file nor a directory' "$pip_log" | tail -n 60 >&2 || true
    die "pip install -r requirements.txt failed (full output: $pip_log)"
  fi
  echo "$req_hash" >"$REQ_STAMP"
  rm -f "$BUILD_STAMP"  # new wheels: rebuild the workspace against them
fi
# colcon's --symlink-install of ament_python packages runs `setup.py develop`, which
# setuptools >= 80 no longer supports; the 3.11 venv bundles 65.x.
"$VPY" - <<'EOF' || die "need setuptools<80 in .venv: .venv/bin/pip install 'setuptools<80'"
import sys
import setuptools
sys.exit(int(setuptools.__version__.split('.')[0]) >= 80)
EOF

# --- 3. quirk: the wheels' rosidl_generator_py CMake exports hard-code the include dirs of the
# machine that built them (/opt/python/cp311-cp311/...). Point them at this venv's Python and
# numpy headers; rewrites only files whose value differs, so it is idempotent and cheap.
"$VPY" - "$VENV/share" <<'EOF'
import re
import sys
import sysconfig
from pathlib import Path

import numpy

want = f'{sysconfig.get_paths()["include"]};{numpy.get_include()}'
line = re.compile(
    r'(__rosidl_generator_py PROPERTIES\n\s*INTERFACE_INCLUDE_DIRECTORIES ")[^"]*(")'
)
for f in Path(sys.argv[1]).glob('*/cmake/*__rosidl_generator_pyExport.cmake'):
    text = f.read_text()
    new = line.sub(lambda m: m.group(1) + want + m.group(2), text)
    if new != text:
        f.write_text(new)
    if '/opt/python/' in new:
        sys.exit(f'[setup] ERROR: {f} still names /opt/python; the wheel format changed')
EOF
py_inc="$("$VPY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
[[ -f "$py_inc/Python.h" ]] \
  || die "no $py_inc/Python.h, needed to build the interfaces (Debian: python3.11-dev)"

# --- 4. colcon build ---------------------------------------------------------------------------
# Hash of what affects the install tree: directories, build files, interface definitions and
# data files. Python modules are left out: --symlink-install links the package dirs, so new or
# edited modules are live without a rebuild.
src_hash="$(
  cd "$WS/src"
  {
    echo "$ROOT $req_hash"
    find . \( -name __pycache__ -o -name '.*_cache' \) -prune \
      -o \( -type d -o ! -name '*.py' \) -print | LC_ALL=C sort
    find . \( -name __pycache__ -o -name '.*_cache' \) -prune -o -type f ! -name '*.py' -print0 \
      | LC_ALL=C sort -z | xargs -0 -r cat
    find . -type f -name setup.py -print0 | LC_ALL=C sort -z | xargs -0 -r cat
  } | sha256sum | cut -d' ' -f1
)"
if [[ "${TSRRT_FORCE_BUILD:-0}" == 1 || ! -f "$WS/install/setup.bash" \
      || "$(cat "$BUILD_STAMP" 2>/dev/null || true)" != "$src_hash" ]]; then
  log "colcon build (ros2_ws)"
  # The wheels install ament packages under the venv prefix (.venv/share/<pkg>).
  export AMENT_PREFIX_PATH="$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  export CMAKE_PREFIX_PATH="$VENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
  export PATH="$VENV/bin:$PATH"
  build_log="$WS/log/tsrrt-colcon-build.txt"
  start=$SECONDS
  # Output goes to a file and is shown only on failure; the CMake hint pins the venv's python
  # so FindPython3 does not pick the system interpreter (its numpy/rosidl modules are absent).
  if ! (cd "$WS" && colcon --log-base log build --base-paths src --build-base build \
        --install-base install --symlink-install \
        --event-handlers console_cohesion+ console_direct- console_stderr- status- \
        --cmake-args -DPython3_EXECUTABLE="$VPY" -DBUILD_TESTING=OFF \
        ) >"$build_log" 2>&1; then
    tail -n 200 "$build_log" >&2
    die "colcon build failed (full output: $build_log)"
  fi
  log "$(grep -E '^Summary:' "$build_log" || echo 'build done') in $((SECONDS - start))s"
  # numba compiles the planner's kernels on first use (about 10 s) and caches them on disk:
  # compile them now, not in a first plan.
  if ! (source "$ROOT/scripts/env.sh" && python -m tsrrt_planner.compile_kernels) \
      >"$WS/log/tsrrt-kernels.txt" 2>&1; then
    tail -n 50 "$WS/log/tsrrt-kernels.txt" >&2
    die "compiling the planner's kernels failed (full output: $WS/log/tsrrt-kernels.txt)"
  fi
  log "$(tail -n 1 "$WS/log/tsrrt-kernels.txt")"
  echo "$src_hash" >"$BUILD_STAMP"
elif [[ "$QUIET" != 1 ]]; then
  log "workspace up to date"
fi
