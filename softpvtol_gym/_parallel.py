"""Large batches split over threads: Python threads each calling a ``nogil`` compiled kernel on a
contiguous range of rows.

Why not numba's ``parallel=True``: its default OpenMP pool spin-waits, and when the machine is busy
(an RL training run beside the simulator, other jobs) a 256-row call took milliseconds instead of
microseconds. Threads blocked on a queue wait passively. Results do not depend on the split: every row
is computed by the same kernel code, alone.
"""

from __future__ import annotations

import concurrent.futures
import os
import threading

import numba
import numpy as np

#: batches of at least this many rows are split (each thread gets at least half of it)
MIN_ROWS = 512

_pool: concurrent.futures.ThreadPoolExecutor | None = None
_pool_pid: int | None = None


def thread_count() -> int:
    """Threads a large batch is split over: ``NUMBA_NUM_THREADS`` (default: the number of CPUs)."""
    return max(1, int(numba.config.NUMBA_NUM_THREADS))


#: most rows in one chunk of a split batch
MAX_CHUNK = 1024


def row_ranges(n: int, align: int = 1) -> list[tuple[int, int]]:
    """Contiguous (lo, hi) chunks covering n rows (lo a multiple of ``align``): one chunk below
    ``MIN_ROWS`` or with one thread, else at least two per thread and at most ``MAX_CHUNK`` rows each."""
    threads = thread_count()
    if n < MIN_ROWS or threads <= 1:
        return [(0, n)]
    per = min(MAX_CHUNK, -(-n // (2 * threads)))
    per = -(-per // align) * align
    return [(lo, min(n, lo + per)) for lo in range(0, n, per)]


def run_split(fn, ranges: list[tuple[int, int]], side=None, after=None) -> None:
    """fn(lo, hi) for every range, the ranges taken in turn by this thread and the pool's threads
    (dynamic scheduling: a thread that the OS does not run, on a busy machine, holds up one chunk at
    most). ``side()``, if given, runs first in this thread while the pool's threads start on the ranges.
    ``after(lo, hi)``, if given, runs for each range right after fn(lo, hi), in the same thread (while the
    range's rows are in that thread's cache), once ``side()`` has returned; if ``side()`` raises, every range
    still gets fn, none gets ``after``, and the error propagates once every thread is done."""
    global _pool, _pool_pid
    if len(ranges) == 1:
        fn(*ranges[0])
        if side is not None:
            side()
        if after is not None:
            after(*ranges[0])
        return
    if _pool is None or _pool_pid != os.getpid():  # a forked child does not inherit the threads
        _pool = concurrent.futures.ThreadPoolExecutor(max_workers=max(1, thread_count() - 1),
                                                      thread_name_prefix="softpvtol")
        _pool_pid = os.getpid()
    todo = iter(ranges)  # next() on a list iterator is atomic under the GIL
    side_done = threading.Event()
    side_error: list[BaseException] = []

    def work() -> None:
        for lo, hi in todo:
            fn(lo, hi)
            if after is not None:
                side_done.wait()
                if not side_error:
                    after(lo, hi)

    futures = [_pool.submit(work) for _ in range(min(thread_count() - 1, len(ranges) - 1))]
    try:
        if side is not None:
            try:
                side()
            except BaseException as exc:  # every range is still stepped; side()'s error is raised at the end
                side_error.append(exc)
        side_done.set()
        work()
    finally:
        side_done.set()
        concurrent.futures.wait(futures)
    for f in futures:
        f.result()
    if side_error:
        raise side_error[0]


def run_rows(kernel, n: int, *args) -> None:
    """kernel(*args), with every array argument of n rows cut to the rows of each thread's range
    (other arguments, e.g. a parameter matrix of one row, are passed whole)."""
    ranges = row_ranges(n)
    if len(ranges) == 1:
        kernel(*args)
        return

    def part(lo: int, hi: int) -> None:
        kernel(*[a[lo:hi] if isinstance(a, np.ndarray) and a.ndim and a.shape[0] == n else a for a in args])

    run_split(part, ranges)
