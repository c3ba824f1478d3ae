"""N jobs, wherever they run: the one call the study's code makes to get work done.

``run_jobs(fn, calls, workers=..., cluster=...)`` runs ``fn(*call)`` for every call here,
side by side in worker processes (:mod:`bgap.runner.pools`), or as Ray tasks
(:mod:`bgap.runner.cluster`), and returns the results in the order of ``calls``: a job
computes the same wherever it runs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from bgap.common.errors import Interrupted
from bgap.runner.cluster import ClusterConfig, run_tasks
from bgap.runner.pools import in_worker, process_pool


def run_jobs(
    fn: Callable[..., Any],
    calls: Sequence[tuple],
    *,
    workers: int = 1,
    numba_threads: int | None = None,
    cluster: ClusterConfig | None = None,
    done: Callable[[int, Any], None] | None = None,
    kept: str = "",
) -> list[Any]:
    """``fn(*call)`` for every call; the results in the order of ``calls``.

    Where: as Ray tasks when ``cluster`` is enabled; else in a pool of ``workers``
    processes (``numba_threads`` kernel threads each; default a share of the cores); else,
    with one worker or one call, here, one after the other. ``done(k, result)`` is called
    here as job ``k`` finishes (progress, saving as it goes). Ctrl-C, or a worker process
    lost, stops the jobs not yet finished and ends in one line: how many had finished,
    and ``kept`` (what was saved, how to continue). Here, a job's own Ctrl-C handling
    speaks for it."""
    if cluster is not None and cluster.enabled:
        return run_tasks(cluster, fn, calls, done, kept)
    results: list[Any] = [None] * len(calls)
    if workers <= 1 or len(calls) <= 1:
        for k, call in enumerate(calls):
            results[k] = fn(*call)
            if done is not None:
                done(k, results[k])
        return results
    with process_pool(min(workers, len(calls)), numba_threads) as pool:
        futures: dict[Any, int] = {}
        finished = 0
        try:  # a Ctrl-C while the workers start is heard as the last one starts
            for k, call in enumerate(calls):
                futures[pool.submit(in_worker, fn, *call)] = k
            for future in as_completed(futures):
                k = futures[future]
                results[k] = future.result()
                finished += 1
                if done is not None:
                    done(k, results[k])
        except (KeyboardInterrupt, BrokenProcessPool) as stop:
            pool.shutdown(wait=True, cancel_futures=True)
            why = "stopped" if isinstance(stop, KeyboardInterrupt) else "a worker process was lost"
            raise Interrupted(
                f"{why}: {finished} of {len(calls)} jobs had finished"
                + (f"; {kept}" if kept else "")
            ) from None
    return results
