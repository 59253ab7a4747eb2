"""A local executor that runs every job in a process of its own, so that a killed worker costs only its job.

``concurrent.futures.ProcessPoolExecutor`` shares its worker processes between jobs: when one is killed (the
OOM killer, ``kill -9``) the pool is *broken* and every job in flight fails with ``BrokenProcessPool``, with no
way to tell which one died. :class:`ProcessPerJobExecutor` has the same ``submit`` / ``Future`` interface
(what :func:`softpvtol_gym.baselines.leaderboard.jobs.run_jobs` takes) but starts one fresh ``spawn`` process per
job (at most ``max_workers`` at a time): a process that dies without a result fails its own future with
:class:`WorkerCrashed` (naming the signal), the other jobs go on. :meth:`shutdown` (also on leaving a ``with``
block, e.g. after Ctrl-C) cancels the jobs not started and terminates, then kills, the running processes, so
that no worker outlives the command. The cost: a fresh interpreter per job (a second or two of imports,
nothing next to a training job).
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import threading
from concurrent.futures import Future, ThreadPoolExecutor

from softpvtol_gym.baselines.util.environment import temporary_environment

#: seconds a terminated worker gets to exit before it is killed
TERMINATE_GRACE_S = 5.0


class WorkerCrashed(RuntimeError):
    """A job's worker process died without a result (killed by a signal, or exited early)."""


def _describe_exit(code: int | None) -> str:
    if code is not None and code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited with code {code} without a result"


def _child(conn, fn, args, kwargs) -> None:
    try:
        result = ("ok", fn(*args, **kwargs))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the driver, as the pool does
        result = ("error", exc)
    try:
        conn.send(result)
    except Exception as exc:  # noqa: BLE001 - an exception or result that does not pickle
        conn.send(("error", RuntimeError(f"{type(result[1]).__name__}: {result[1]} (not picklable: {exc})")))
    finally:
        conn.close()


class ProcessPerJobExecutor:
    """``submit(fn, *args)`` runs ``fn(*args)`` in a new process (``mp_context``, default ``spawn``), at most
    ``max_workers`` at once; the future holds its result, the exception it raised, or :class:`WorkerCrashed`.
    ``worker_env``: environment variables set for the workers only (e.g. ``{"NUMBA_NUM_THREADS": "1"}``)."""

    def __init__(self, max_workers: int, mp_context=None, worker_env: dict[str, str] | None = None):
        self._ctx = mp_context or mp.get_context("spawn")
        self._worker_env = dict(worker_env or {})
        self._threads = ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="job")
        self._procs: set = set()
        self._lock = threading.Lock()
        self._closing = False

    def _run(self, fn, args, kwargs):
        parent, child = self._ctx.Pipe(duplex=False)
        with self._lock:
            if self._closing:
                raise WorkerCrashed("not started: the executor was shut down")
            # not a daemon: a job may start processes of its own; shutdown() stops it explicitly
            proc = self._ctx.Process(target=_child, args=(child, fn, args, kwargs), daemon=False)
            with temporary_environment(self._worker_env):
                proc.start()
            self._procs.add(proc)
        child.close()
        try:
            try:
                status, value = parent.recv()
            except (EOFError, OSError):
                proc.join()
                raise WorkerCrashed(f"worker process {proc.pid} {_describe_exit(proc.exitcode)}") from None
            proc.join()
        finally:
            parent.close()
            with self._lock:
                self._procs.discard(proc)
        if status == "error":
            raise value
        return value

    def submit(self, fn, *args, **kwargs) -> Future:
        return self._threads.submit(self._run, fn, args, kwargs)

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        """Cancel what has not started; terminate (then kill) the running workers if ``cancel_futures`` or the
        call comes from an exception (``__exit__``), else wait for them (``wait``)."""
        if cancel_futures:
            with self._lock:
                self._closing = True
                procs = list(self._procs)
            self._threads.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                if p.is_alive():
                    p.terminate()
            for p in procs:
                p.join(TERMINATE_GRACE_S)
                if p.is_alive():
                    p.kill()
                    p.join()
        self._threads.shutdown(wait=wait)

    def __enter__(self) -> ProcessPerJobExecutor:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.shutdown(wait=True, cancel_futures=exc_type is not None)
