"""N jobs, wherever they run: the one call the study's code makes to get work done.

``run_jobs(fn, calls, workers=..., cluster=...)`` runs ``fn(*call)`` for every call here,
side by side in worker processes (:mod:`bgap.runner.pools`), or as Ray tasks
(:mod:`bgap.runner.cluster`), and returns the results in the order of ``calls``: a job
computes the same wherever it runs. It also owns what goes with running them: the threads
a job gets, the progress shown while they run (:mod:`bgap.runner.progress`) and Ctrl-C.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack
from functools import partial
from typing import Any

from tqdm.auto import tqdm

from bgap.common.errors import Interrupted
from bgap.runner.cluster import ClusterConfig, run_tasks
from bgap.runner.pools import in_worker, process_pool
from bgap.runner.progress import JobBars
from bgap.runner.threads import set_threads


def run_jobs(
    fn: Callable[..., Any],
    calls: Sequence[tuple],
    *,
    workers: int = 1,
    numba_threads: int | None = None,
    torch_threads: int | None = None,
    cluster: ClusterConfig | None = None,
    for_cluster: Callable[[Sequence[tuple]], Sequence[tuple]] | None = None,
    done: Callable[[int, Any], None] | None = None,
    kept: str = "",
    bar: tuple[str, str, int] | None = None,
    job_bars: Sequence[tuple[str, int]] | None = None,
) -> list[Any]:
    """``fn(*call)`` for every call; the results in the order of ``calls``.

    Where: as Ray tasks when ``cluster`` is enabled (each call passed through
    ``for_cluster`` first, e.g. a model file sent as its bytes); else in a pool of
    ``workers`` processes (one torch thread and ``numba_threads`` kernel threads each;
    default a share of the cores); else, with one worker or one call, here, one after the
    other, with ``torch_threads`` torch threads when given. ``done(k, result)`` is called
    here as job ``k`` finishes (saving as it goes).

    Progress: ``bar=(desc, unit, per_job)`` draws one bar that moves ``per_job`` as each
    job finishes. ``job_bars=[(name, total), ...]`` draws one bar per job run in another
    process, which the job moves itself: ``fn`` then takes a ``report`` keyword, a
    :class:`~bgap.runner.progress.Reporter` there and None here (where a job may draw its
    own).

    Ctrl-C, or a worker process lost, stops the jobs not yet finished and ends in one line:
    how many had finished, and ``kept`` (what was saved, how to continue). Here, a job's own
    Ctrl-C handling speaks for it."""
    on_cluster = cluster is not None and cluster.enabled
    here = not on_cluster and (workers <= 1 or len(calls) <= 1)
    with ExitStack() as shown:
        bars = None
        if job_bars:  # drawn here for jobs in this machine's other processes
            names, totals = zip(*job_bars, strict=True)
            bars = shown.enter_context(JobBars(names, totals, enabled=not here and not on_cluster))
            calls = [(*call, bars.reporter(k)) for k, call in enumerate(calls)]
            fn = partial(_reporting, fn)
        count = (
            shown.enter_context(tqdm(total=len(calls) * bar[2], desc=bar[0], unit=bar[1]))
            if bar
            else None
        )

        def finished(k: int, result: Any) -> None:
            if done is not None:
                done(k, result)
            if count is not None:
                count.update(bar[2])
            if bars is not None and bars.enabled:
                bars.write(f"finished: {bars.names[k]}")

        if on_cluster:
            shipped = for_cluster(calls) if for_cluster is not None else calls
            return run_tasks(cluster, fn, shipped, finished, kept)
        if here:
            if torch_threads is not None:
                set_threads(torch_threads)
            return _here(fn, calls, finished)
        return _side_by_side(fn, calls, workers, numba_threads, finished, kept)


def _reporting(fn: Callable[..., Any], *call: Any) -> Any:
    """``fn`` with its call's last item as its ``report`` keyword."""
    *args, report = call
    return fn(*args, report=report)


def _here(fn: Callable[..., Any], calls: Sequence[tuple], finished: Callable) -> list[Any]:
    results: list[Any] = []
    for k, call in enumerate(calls):
        results.append(fn(*call))
        finished(k, results[k])
    return results


def _side_by_side(
    fn: Callable[..., Any],
    calls: Sequence[tuple],
    workers: int,
    numba_threads: int | None,
    finished: Callable,
    kept: str,
) -> list[Any]:
    results: list[Any] = [None] * len(calls)
    with process_pool(min(workers, len(calls)), numba_threads) as pool:
        futures: dict[Any, int] = {}
        n_done = 0
        try:  # a Ctrl-C while the workers start is heard as the last one starts
            for k, call in enumerate(calls):
                futures[pool.submit(in_worker, fn, *call)] = k
            for future in as_completed(futures):
                k = futures[future]
                results[k] = future.result()
                n_done += 1
                finished(k, results[k])
        except (KeyboardInterrupt, BrokenProcessPool) as stop:
            pool.shutdown(wait=True, cancel_futures=True)
            why = "stopped" if isinstance(stop, KeyboardInterrupt) else "a worker process was lost"
            raise Interrupted(
                f"{why}: {n_done} of {len(calls)} jobs had finished" + (f"; {kept}" if kept else "")
            ) from None
    return results
