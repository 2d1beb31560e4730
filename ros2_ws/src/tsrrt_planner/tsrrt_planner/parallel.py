"""TASK_SPACE_RRT on several cores: independent seeds, one process each, the best plan kept.

Why: one search uses one core, and where it ends depends on its seed as well as its time.
On tset12 at 10 s a fifth of the seeds end within 1 % of the lower bound and half end more
than 10 % above it (docs/planner.md, *Parallel searches*). A portfolio of seeds, as OMPL's
ParallelPlan and MoveIt's parallel planning pipelines run, keeps the best of them in the same
wall time on a machine with a core to spare: on tset12's seeds 2000-2023, 3.6 % above the
bound (median) against 18.4 % for one search. Two ways of giving one search the second core
instead (workers sharing their best plans, a helper extending one tree) did no better.

Each worker is a forked process: it inherits the problem and the compiled kernels, so nothing
is pickled on the way in and a replan starts in milliseconds; only progress and the result come
back through a pipe. Worker k searches with seed `seed + k * SEED_STRIDE`, so worker 0 is the
single search of the same seed, and the portfolio is deterministic for a seed and a node budget
like TASK_SPACE_RRT itself.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import threading
import time
import traceback
from multiprocessing.connection import Connection, wait
from typing import Any

from tsrrt_planner.errors import PlannerError
from tsrrt_planner.problem import PlanningProblem
from tsrrt_planner.task_space_rrt import (
    TASK_SPACE_RRT,
    Cancel,
    PlanResult,
    Progress,
    ProgressInfo,
    compile_search_kernels,
)

SEED_STRIDE = 7919          # worker k's seed: seed + k * SEED_STRIDE
FINAL_STOPS = ("recovered", "converged")   # one worker's such stop ends the others' search
POLL_S = 0.05               # how often the coordinator looks at the caller's cancel
JOIN_TIMEOUT_S = 5.0        # a worker that has not exited this long after its result is killed


class WorkerTraceback(Exception):
    """Where a worker's error was raised, as the worker formatted it: the cause of the error
    plan_in_parallel raises again, so that a log of it shows the line that failed."""

    def __str__(self) -> str:
        return f"\n\nin the planning worker:\n{self.args[0]}"


def plan_in_parallel(problem: PlanningProblem, workers: int, mode: str = "tsrrt",
                     seed: int = 0, progress: Progress | None = None,
                     cancel: Cancel | None = None, **options: Any) -> PlanResult:
    """TASK_SPACE_RRT with `workers` seeds at once; the plan whose end cost (charged
    `push_cost` per push, as the search charges it) is least wins, ties to the lower worker.

    `options` are TASK_SPACE_RRT's keyword arguments. With one worker this is TASK_SPACE_RRT in
    this process. The result's `nodes` and trace count every worker's nodes (each as of its
    last report), its trace is the best cost over all workers, its `elapsed_s` the wall time
    of the whole call and its `seed` the call's. Progress reports the same, from this process.
    A worker's error is raised here, after the others have been stopped, with the worker's
    traceback as its cause (WorkerTraceback): the error's own traceback ends at this function.
    """
    if not isinstance(workers, int) or workers < 1:
        raise PlannerError(f"workers must be an integer >= 1, got {workers!r}")
    if workers == 1:
        return TASK_SPACE_RRT(problem, mode, seed, progress=progress, cancel=cancel, **options)
    cancelled = cancel.is_set if isinstance(cancel, threading.Event) else cancel
    if mode == "tsrrt":
        compile_search_kernels(problem)   # once here, inherited by every worker
    context = multiprocessing.get_context("fork")
    stop = context.Event()
    began = time.perf_counter()
    channels: dict[Connection, int] = {}
    processes = []
    for worker in range(workers):
        receiving, sending = context.Pipe(duplex=False)
        process = context.Process(
            target=_search, name=f"tsrrt-planner-{worker}", daemon=True,
            args=(sending, stop, problem, mode, seed + worker * SEED_STRIDE, options))
        process.start()
        sending.close()
        channels[receiving] = worker
        processes.append(process)
    latest = [ProgressInfo(0.0, 1, math.inf) for _ in range(workers)]
    results: dict[int, tuple[float, PlanResult]] = {}
    try:
        while len(results) < workers:
            if cancelled is not None and cancelled():
                stop.set()
            for channel in wait(list(channels), timeout=POLL_S):
                worker = channels[channel]
                try:
                    kind, payload = channel.recv()
                except EOFError:
                    processes[worker].join(JOIN_TIMEOUT_S)
                    raise PlannerError(
                        f"planning worker {worker} exited without a result (exit code "
                        f"{processes[worker].exitcode})") from None
                if kind == "error":
                    error, trace = payload
                    raise error from WorkerTraceback(trace)
                if kind == "result":
                    results[worker] = payload
                    del channels[channel]
                    channel.close()
                    if payload[1].stop_reason in FINAL_STOPS:
                        stop.set()
                    continue
                latest[worker] = payload
                if progress is not None:
                    progress(ProgressInfo(time.perf_counter() - began,
                                          sum(info.nodes for info in latest),
                                          min(info.best_cost for info in latest)))
    finally:
        stop.set()
        for channel in channels:
            channel.close()
        for process in processes:
            process.join(JOIN_TIMEOUT_S)
            if process.is_alive():
                process.kill()
                process.join()
    return best_of(results, began, options.get("push_cost", 0.0), seed)


def _search(channel: Connection, stop: Any, problem: PlanningProblem, mode: str, seed: int,
            options: dict[str, Any]) -> None:
    """One worker: the search, with progress and the result (or its error) sent back. It
    leaves by os._exit at once: a fork of the planner node must run none of the node's exit
    handlers, nor flush a stream another of its threads may have held at the fork."""
    began = time.perf_counter()
    code = 1
    try:
        result = TASK_SPACE_RRT(problem, mode, seed, cancel=stop.is_set,
                                progress=lambda info: channel.send(("progress", info)),
                                **options)
        channel.send(("result", (began, result)))
        code = 0
    except Exception as error:   # raised again by the coordinator
        channel.send(("error", (error, traceback.format_exc())))
    finally:
        channel.close()
        os._exit(code)


def best_of(results: dict[int, tuple[float, PlanResult]], began: float, push_cost: float,
            seed: int) -> PlanResult:
    """The winning worker's plan with the portfolio's bookkeeping: nodes of every worker, the
    trace of the best cost over all of them (times from `began`), the call's seed."""
    def charged(worker: int) -> tuple[float, int]:
        result = results[worker][1]
        return result.best_cost + push_cost * len(result.steps), worker

    winner = results[min(results, key=charged)][1]
    events = sorted((started - began + elapsed, worker, nodes, cost)
                    for worker, (started, result) in results.items()
                    for elapsed, nodes, cost in result.trace)
    nodes_of = dict.fromkeys(results, 1)
    best = math.inf
    trace: list[tuple[float, int, float]] = []
    for elapsed, worker, nodes, cost in events:
        nodes_of[worker] = nodes
        if cost < best:
            best = cost
            trace.append((max(elapsed, 0.0), sum(nodes_of.values()), cost))
    return PlanResult(
        mode=winner.mode, seed=seed, steps=winner.steps, states=winner.states,
        costs=winner.costs, nodes=sum(result.nodes for _, result in results.values()),
        elapsed_s=time.perf_counter() - began, trace=tuple(trace),
        stop_reason=winner.stop_reason, lower_bound=winner.lower_bound)
