"""The compiled kernels' home (kernels.py)."""

from __future__ import annotations

from pathlib import Path

import tsrrt_planner


def test_every_compiled_kernel_lives_in_kernels_py():
    """numba's on-disk cache notices a change only in a kernel's own file, and a cached kernel
    carries the code of every kernel it calls: a kernel defined in another module would leave
    its cached callers running its old code after an edit."""
    package = Path(tsrrt_planner.__file__).resolve().parent
    elsewhere = [path.name for path in sorted(package.glob("*.py"))
                 if path.name != "kernels.py"
                 and any(mark in path.read_text()
                         for mark in ("njit", "@kernel", "import numba", "from numba"))]
    assert elsewhere == []
