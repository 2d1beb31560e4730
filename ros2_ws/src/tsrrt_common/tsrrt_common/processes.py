"""Stopping a child process group the way a terminal does: a signal, a grace period, SIGKILL.

Nodes started with `start_new_session=True` lead their own process group, so the signal reaches
a launcher script and the nodes it started alike. Before the SIGKILL, the group gets SIGUSR1: every
tsrrt node prints all its threads' stacks on it (run_node registers faulthandler), so a node that
hangs on a signal leaves in its log where it hung rather than nothing.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time

STACK_REPORT_WAIT_S = 1.0   # time given to the stack reports (SIGUSR1) before the SIGKILL


def stop_process_group(process: subprocess.Popen, sig: int = signal.SIGINT,
                       grace_s: float = 15.0) -> int:
    """Signal the group of `process`, wait up to `grace_s`, then SIGUSR1 and SIGKILL; the exit
    code."""
    if process.poll() is None:
        os.killpg(process.pid, sig)
        try:
            process.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGUSR1)
            time.sleep(STACK_REPORT_WAIT_S)
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=10)
    return process.returncode
