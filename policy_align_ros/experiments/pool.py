"""The experiments' one process pool: a function mapped over data sets on worker processes.

Every benchmark that runs data sets in parallel (``bench toy``, ``suite``, ``grasp``,
``humanoid``, ``tools/recording_check.py``) goes through :func:`parallel_map`.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager

__all__ = ["parallel_map"]

#: Environment variables that set the BLAS thread count of a new process.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def _single_threaded_blas() -> Iterator[None]:
    """One BLAS thread in the processes spawned within; the environment is restored."""
    saved = {k: os.environ.get(k) for k in BLAS_THREAD_VARIABLES}
    try:
        os.environ.update({k: "1" for k in BLAS_THREAD_VARIABLES})
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def parallel_map(func: Callable, tasks: Sequence, jobs: int, label: str | None = None
                 ) -> list:
    """``[func(t) for t in tasks]`` on ``jobs`` worker processes, results in task order.

    With ``jobs <= 1`` (or a single task) the tasks run in this process. Workers are
    spawned with one BLAS thread each: ``jobs`` processes on as many cores are faster
    than processes that each start a BLAS thread per core. ``func`` must be a module-level
    function (spawned workers import it).

    Parameters
    ----------
    func : callable
        ``func(task) -> result``.
    tasks : sequence
        One entry per call (picklable).
    jobs : int
        Number of worker processes.
    label : str, optional
        Prefix of a progress line on stderr (count done and seconds left); None: silent.
    """
    tasks = list(tasks)
    start = time.perf_counter()
    step = max(1, len(tasks) // 20)

    def report(done: int) -> None:
        if label is not None and (done % step == 0 or done == len(tasks)):
            left = (time.perf_counter() - start) / done * (len(tasks) - done)
            print(f"\r{label}: {done}/{len(tasks)} ({left:.0f} s left)   ",
                  end="", file=sys.stderr, flush=True)

    results = []
    if jobs <= 1 or len(tasks) <= 1:
        for task in tasks:
            results.append(func(task))
            report(len(results))
    else:
        with _single_threaded_blas(), ProcessPoolExecutor(
                max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            for result in pool.map(func, tasks):
                results.append(result)
                report(len(results))
    if label is not None:
        print(file=sys.stderr)
    return results
