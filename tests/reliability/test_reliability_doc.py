"""docs/reliability.md lists exactly the suite's bad-input cases, in the suite's order.

The rows come from collecting tests/reliability in a subprocess (conftest.py writes each case's
category, input, expected code and message fragment); the document's table must match them line
for line, so a case added, changed or removed shows up here until the document follows.
`python tests/reliability/test_reliability_doc.py` prints the table to paste.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "reliability.md"
HEADER = "| category | input | expected | message contains |"
MINIMUM_CASES = 30


@cache
def suite_rows() -> list[dict[str, str]]:
    with tempfile.TemporaryDirectory() as folder:
        target = Path(folder) / "rows.json"
        result = subprocess.run(
            [sys.executable, "-m", "pytest", str(ROOT / "tests" / "reliability"),
             "--collect-only", "-q", "-p", "no:cacheprovider"],
            cwd=ROOT, env=dict(os.environ, TSRRT_BAD_INPUT_TABLE=str(target)),
            capture_output=True, text=True, check=False)
        assert result.returncode == 0, result.stdout + result.stderr
        return json.loads(target.read_text())


def table_lines(rows: list[dict[str, str]]) -> list[str]:
    return [f"| {r['category']} | {r['what']} | {r['code']} | `{r['fragment']}` |" for r in rows]


def documented_lines() -> list[str]:
    lines = DOC.read_text().splitlines()
    start = lines.index(HEADER) + 2          # past the header and its |---| line
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")),
               len(lines))
    return lines[start:end]


def test_the_document_lists_every_case_of_the_suite():
    rows = suite_rows()
    assert len(rows) >= MINIMUM_CASES
    expected = table_lines(rows)
    assert documented_lines() == expected, "docs/reliability.md should list:\n" + "\n".join(
        [HEADER, "|---|---|---|---|", *expected])


def test_every_category_of_the_issue_has_cases():
    categories = {row["category"] for row in suite_rows()}
    assert categories == {"scenario and objective files", "action goals and service requests",
                          "parameters", "messages", "model files"}


if __name__ == "__main__":
    print("\n".join([HEADER, "|---|---|---|---|", *table_lines(suite_rows())]))
