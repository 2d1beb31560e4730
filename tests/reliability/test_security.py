"""No file or message is ever executed: the source holds no pickle, eval/exec or unsafe YAML.

Every Python file of the packages, scripts and tests is parsed and its syntax tree searched, so
comments and strings do not count and aliases (`import pickle as p`) do; the shell scripts are
searched for `eval`. The scanner itself is checked against a sample holding each forbidden
construct, so this test cannot pass by finding nothing. Discovery stays on this machine unless a
user opts out: env.sh sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
"""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ["ros2_ws/src", "scripts", "tests"]
FORBIDDEN_MODULES = {"pickle", "cPickle", "_pickle", "dill", "shelve", "marshal", "jsonpickle",
                     "cloudpickle", "joblib"}
FORBIDDEN_BUILTINS = {"eval", "exec", "compile", "__import__"}
UNSAFE_YAML = {"load", "load_all", "unsafe_load", "unsafe_load_all", "full_load",
               "full_load_all"}
SAFE_LOADERS = {"SafeLoader", "CSafeLoader", "BaseLoader", "CBaseLoader"}
UNSAFE_LOADERS = {"Loader", "UnsafeLoader", "FullLoader", "CLoader", "CUnsafeLoader",
                  "CFullLoader"}
SHELL_CALLS = {("os", "system"), ("os", "popen")}


def _dotted(node: ast.AST) -> str:
    """'a.b.c' of a Name/Attribute chain, '' for anything else."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value)
        return f"{base}.{node.attr}" if base else ""
    return ""


def _is_true(node: ast.AST) -> bool:
    return isinstance(node, ast.Constant) and node.value is True


def unsafe_constructs(source: str) -> list[str]:
    """'line: what' for every construct that could execute data."""
    found = []
    for node in ast.walk(ast.parse(source)):
        line = getattr(node, "lineno", 0)
        if isinstance(node, ast.Import):
            found += [f"{line}: import {a.name}" for a in node.names
                      if a.name.split(".")[0] in FORBIDDEN_MODULES]
        elif isinstance(node, ast.ImportFrom) and node.module \
                and node.module.split(".")[0] in FORBIDDEN_MODULES:
            found.append(f"{line}: from {node.module} import")
        elif isinstance(node, ast.Attribute) and node.attr in UNSAFE_LOADERS \
                and _dotted(node.value) == "yaml":
            found.append(f"{line}: yaml.{node.attr}")
        elif isinstance(node, ast.Call):
            name = _dotted(node.func)
            keywords = {k.arg: k.value for k in node.keywords}
            if name in FORBIDDEN_BUILTINS:
                found.append(f"{line}: {name}()")
            elif name.startswith("yaml.") and name[5:] in UNSAFE_YAML:
                loader = _dotted(keywords.get("Loader", ast.Constant(None))).split(".")[-1]
                if loader not in SAFE_LOADERS:
                    found.append(f"{line}: {name}() without a safe Loader")
            elif tuple(name.rsplit(".", 1)) in SHELL_CALLS:
                found.append(f"{line}: {name}()")
            elif _is_true(keywords.get("shell", ast.Constant(None))):
                found.append(f"{line}: {name}(shell=True)")
            elif _is_true(keywords.get("allow_pickle", ast.Constant(None))):
                found.append(f"{line}: {name}(allow_pickle=True)")
            elif name == "torch.load":
                found.append(f"{line}: torch.load()")
    return found


UNSAFE_SAMPLE = """
import pickle
import dill as d
from shelve import open
import yaml
import numpy as np
import os, subprocess
eval("1")
exec("x = 1")
yaml.load(text)
yaml.load(text, Loader=yaml.Loader)
yaml.unsafe_load(text)
yaml.full_load(text)
np.load("f.npy", allow_pickle=True)
os.system("ls")
subprocess.run("ls", shell=True)
"""
SAFE_SAMPLE = """
import yaml, re, subprocess
yaml.safe_load(text)
yaml.load(text, Loader=yaml.SafeLoader)
re.compile("x")
subprocess.run(["ls"], check=False)
# eval(pickle.loads(x)) in a comment
print("yaml.load(x) in a string")
"""


def test_the_scanner_finds_every_unsafe_construct_and_nothing_else():
    found = unsafe_constructs(UNSAFE_SAMPLE)
    assert len(found) == 13, found
    assert unsafe_constructs(SAFE_SAMPLE) == []


def python_files() -> list[Path]:
    files = [p for folder in SOURCES for p in (ROOT / folder).rglob("*.py")
             if not {"build", "install", "log", "__pycache__"} & set(p.parts)]
    assert len(files) > 50, files
    return sorted(files)


def test_no_source_file_can_execute_data():
    problems = [f"{path.relative_to(ROOT)}:{finding}" for path in python_files()
                for finding in unsafe_constructs(path.read_text())]
    assert problems == []


def test_no_shell_script_uses_eval():
    scripts = sorted((ROOT / "scripts").glob("*.sh"))
    assert scripts
    problems = [f"{path.name}:{number}" for path in scripts
                for number, line in enumerate(path.read_text().splitlines(), 1)
                if re.search(r"(^|[;&|\s])eval\s", line.split("#", 1)[0])]
    assert problems == []


def test_discovery_stays_on_this_machine_by_default():
    """A shell that sourced env.sh (test.sh, bringup.sh and demo.sh do) limits DDS discovery
    to localhost unless the caller chose otherwise."""
    command = (f"unset ROS_AUTOMATIC_DISCOVERY_RANGE; source {ROOT / 'scripts' / 'env.sh'} "
               "&& echo $ROS_AUTOMATIC_DISCOVERY_RANGE")
    result = subprocess.run(["bash", "-c", command], capture_output=True, text=True, cwd=ROOT,
                            check=False)
    assert result.stdout.strip().splitlines()[-1:] == ["LOCALHOST"], result.stderr
    assert "source scripts/env.sh" in (ROOT / "scripts" / "test.sh").read_text()
