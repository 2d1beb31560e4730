"""The compiled kernels' home (kernels.py)."""

from __future__ import annotations

import re
from pathlib import Path

import tsrrt_planner

COMPILED = re.compile(r"^\s*(import numba|from numba\b.* import|@kernel|@njit|.*\bnjit\()", re.M)


def test_every_compiled_kernel_lives_in_kernels_py():
    """numba's on-disk cache notices a change only in a kernel's own file, and a cached kernel
    carries the code of every kernel it calls: a kernel defined in another module would leave
    its cached callers running its old code after an edit."""
    package = Path(tsrrt_planner.__file__).resolve().parent
    homes = [path.name for path in sorted(package.glob("*.py"))
             if COMPILED.search(path.read_text())]
    assert homes == ["kernels.py"]
