"""The bad-input suite's table of cases, collected from the tests themselves.

A bad-input test is parametrised with `what` (the input, in words), `code` (the error code or
exception expected) and `fragment` (text the error message must contain: the offending field or
value); its module names its CATEGORY. docs/reliability.md lists the same rows, and
test_reliability_doc.py checks that they agree, so neither can drift from the other. With
TSRRT_BAD_INPUT_TABLE=<path> set, collection writes the rows there as JSON.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

TABLE_ENV = "TSRRT_BAD_INPUT_TABLE"


def bad_input_row(item: pytest.Item) -> dict[str, str] | None:
    """The table row of a bad-input test case, None for other tests."""
    params = getattr(getattr(item, "callspec", None), "params", {})
    category = getattr(getattr(item, "module", None), "CATEGORY", None)
    if category is None or not {"what", "code", "fragment"} <= set(params):
        return None
    return {"category": category, "what": params["what"], "code": params["code"],
            "fragment": params["fragment"]}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    target = os.environ.get(TABLE_ENV)
    if not target:
        return
    rows = [row for item in items if (row := bad_input_row(item)) is not None]
    Path(target).write_text(json.dumps(rows, indent=1))
