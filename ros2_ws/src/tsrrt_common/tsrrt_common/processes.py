"""Stopping a child process group the way a terminal does: a signal, a grace period, SIGKILL.

Nodes started with `start_new_session=True` lead their own process group, so the signal reaches
a launcher script and the nodes it started alike.
"""

from __future__ import annotations

import os
import signal
import subprocess


def stop_process_group(process: subprocess.Popen, sig: int = signal.SIGINT,
                       grace_s: float = 15.0) -> int:
    """Signal the group of `process`, wait up to `grace_s`, then SIGKILL; the exit code."""
    if process.poll() is None:
        os.killpg(process.pid, sig)
        try:
            process.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=10)
    return process.returncode
