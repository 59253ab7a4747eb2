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

import numba
import numpy as np

#: batches of at least this many rows are split (each thread gets at least half of it)
MIN_ROWS = 512

_pool: concurrent.futures.ThreadPoolExecutor | None = None
_pool_pid: int | None = None


def thread_count() -> int:
    """Threads a large batch is split over: ``NUMBA_NUM_THREADS`` (default: the number of CPUs)."""
    return max(1, int(numba.config.NUMBA_NUM_THREADS))


def row_ranges(n: int, align: int = 1) -> list[tuple[int, int]]:
    """Contiguous (lo, hi) ranges covering n rows, one per thread, lo a multiple of ``align``."""
    threads = min(thread_count(), n // (MIN_ROWS // 2)) if n >= MIN_ROWS else 1
    if threads <= 1:
        return [(0, n)]
    per = -(-(-(-n // threads)) // align) * align
    return [(lo, min(n, lo + per)) for lo in range(0, n, per)]


def run_split(fn, ranges: list[tuple[int, int]]) -> list:
    """fn(lo, hi) for every range: the first in this thread, the others in a shared thread pool."""
    global _pool, _pool_pid
    if len(ranges) == 1:
        return [fn(*ranges[0])]
    if _pool is None or _pool_pid != os.getpid():  # a forked child does not inherit the threads
        _pool = concurrent.futures.ThreadPoolExecutor(max_workers=max(1, thread_count() - 1),
                                                      thread_name_prefix="softpvtol")
        _pool_pid = os.getpid()
    futures = [_pool.submit(fn, lo, hi) for lo, hi in ranges[1:]]
    first = fn(*ranges[0])
    return [first] + [f.result() for f in futures]


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
