#!/usr/bin/env bash
# Lint and test: sets up the workspace (silent when up to date), then `ruff check` and pytest.
# Extra arguments go to pytest, e.g. `scripts/test.sh -m "not slow" -x`.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

TSRRT_SETUP_QUIET=1 bash scripts/setup.sh

# A random DDS domain per run so concurrent runs (or a stray node) on this machine do not see
# each other; a caller's choice wins. Linux domain ids 0..101 map to valid UDP ports.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((RANDOM % 101 + 1))}"
# shellcheck source=scripts/env.sh
source scripts/env.sh

# Lint findings fail the run, but pytest still runs so one CI run shows both.
echo "[test] ruff check"
ruff_rc=0
ruff check . || ruff_rc=$?
echo "[test] pytest (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)"
# pytest's own exit code, so "no tests collected" (5) fails the run too.
pytest_rc=0
python -m pytest "$@" || pytest_rc=$?
if ((ruff_rc != 0)); then
  echo "[test] FAILED: ruff check (exit $ruff_rc)" >&2
fi
if ((pytest_rc != 0)); then
  echo "[test] FAILED: pytest (exit $pytest_rc)" >&2
  exit "$pytest_rc"
fi
exit "$ruff_rc"
