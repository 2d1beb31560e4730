"""Stopping a process group: the signal, the grace period, and the stack report before SIGKILL."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from tsrrt_common.processes import stop_process_group

# A process that registers the stack report as run_node does and then ignores SIGTERM: the
# kind of hang the report is for.
STUBBORN = textwrap.dedent("""
    import faulthandler, signal, sys, time
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    print("ready", flush=True)
    def stuck_here():
        time.sleep(60)
    stuck_here()
""")


def start(code: str, log: Path) -> subprocess.Popen:
    with log.open("w") as output:
        process = subprocess.Popen([sys.executable, "-c", code], stdout=output,
                                   stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 10.0
    while "ready" not in log.read_text() and time.monotonic() < deadline:
        time.sleep(0.05)
    return process


def test_a_process_that_stops_on_the_signal_returns_its_code(tmp_path: Path) -> None:
    process = start("print('ready', flush=True)\nimport time\ntime.sleep(60)", tmp_path / "log")
    assert stop_process_group(process, signal.SIGTERM, grace_s=5.0) == -signal.SIGTERM


def test_a_process_that_ignores_the_signal_reports_where_it_hung_then_is_killed(
        tmp_path: Path) -> None:
    log = tmp_path / "log"
    process = start(STUBBORN, log)
    assert stop_process_group(process, signal.SIGTERM, grace_s=0.5) == -signal.SIGKILL
    report = log.read_text()
    assert "stuck_here" in report, report
