"""README.md's interface tables are what `scripts/interface_tables.py` reads from the nodes now:
a node that gains or loses a topic, service, action or parameter fails this test until the
tables are regenerated."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts/interface_tables.py"
README = ROOT / "README.md"
ENTRY_POINT = re.compile(r"'(\w+) = (\w+)\.\w+:main'")


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True,
                          timeout=180)


def test_readme_tables_match_the_nodes():
    result = run("--check")
    assert result.returncode == 0, result.stdout + result.stderr


def test_every_console_script_has_a_table():
    """The tables cover each node setup.py installs for `ros2 run`, found in the sources."""
    text = README.read_text()
    nodes = [m for p in ROOT.glob("ros2_ws/src/*/setup.py")
             for m in ENTRY_POINT.findall(p.read_text())]
    assert len(nodes) == 4
    for executable, package in nodes:
        assert f"#### `{executable}` (`ros2 run {package} {executable}`)" in text


def test_check_fails_on_a_stale_table_and_a_rewrite_fixes_it(tmp_path):
    readme = tmp_path / "README.md"
    current = README.read_text()
    row = next(line for line in current.splitlines() if line.startswith("| `planning_budget_s` |"))
    stale = current.replace(row, row.replace("| double |", "| integer |"))
    assert stale != current
    readme.write_text(stale)
    result = run("--check", "--readme", str(readme))
    assert result.returncode == 1
    assert f"+{row}" in result.stdout
    assert readme.read_text() == stale                        # --check changes nothing
    assert run("--readme", str(readme)).returncode == 0
    assert readme.read_text() == current
