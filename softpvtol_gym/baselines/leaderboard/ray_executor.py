"""Ray as the scale-out engine: a ``concurrent.futures``-style executor over Ray tasks, and Ray's start-up.

:class:`RayExecutor` has the ``submit`` / ``Future`` interface that
:func:`softpvtol_gym.baselines.leaderboard.jobs.run_jobs` takes, so the leaderboard's job list runs on Ray through
the same code as on the local process pool: the same job body
(:func:`softpvtol_gym.baselines.leaderboard.jobs.run_job`), the same skipping of finished jobs, the same result
files. Each task asks Ray for one CPU (``num_cpus=1``) and runs with one numba thread (``NUMBA_NUM_THREADS=1`` in the
job's runtime environment) and one torch thread, so that N CPUs run N jobs without oversubscription.

:func:`start_ray` starts a local Ray instance (no dashboard, in a fresh short temporary directory: Ray's
Unix socket paths must stay under about 107 characters) or connects to an existing cluster
(``address="auto"`` or ``"HOST:PORT"``). On a cluster the job root must be on a file system that every
node mounts at the same path: :func:`softpvtol_gym.baselines.leaderboard.jobs.run_jobs` with ``check_root=True``
makes a task that cannot see the driver's root fail with a message saying so, instead of writing its results where
nobody looks.

Needs the ``distributed`` extra (``pip install 'softpvtol-gym[distributed]'``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import tempfile
import threading
from concurrent.futures import Future
from pathlib import Path

import softpvtol_gym
from softpvtol_gym.baselines.errors import ConfigError

#: environment of every Ray task and actor this project starts: one numba / BLAS thread per CPU asked
TASK_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
            "OPENBLAS_NUM_THREADS": "1"}
#: Ray's Unix sockets live under the temporary directory; their paths must stay under ~107 characters
MAX_TEMP_DIR_CHARS = 40
#: the folder this process imports ``softpvtol_gym`` from (a checkout's root with an editable install)
IMPORT_ROOT = Path(softpvtol_gym.__file__).resolve().parents[1]


def _short_temp_dir() -> str:
    """A fresh, short temporary directory for a local Ray instance (the system's if short enough, else /tmp)."""
    base = tempfile.gettempdir()
    if len(base) > MAX_TEMP_DIR_CHARS - 12:
        base = "/tmp"
    return tempfile.mkdtemp(prefix="ray-", dir=base)


def runtime_env() -> dict:
    """Ray's runtime environment for this project's tasks: :data:`TASK_ENV`, and the driver's
    ``PYTHONPATH`` with the folder this process imports ``softpvtol_gym`` from first (so that a local
    instance imports the same code as the
    driver; on a cluster, the project must be installed, or checked out at the same path, on every node)."""
    path = os.pathsep.join(p for p in (str(IMPORT_ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return {"env_vars": {**TASK_ENV, "PYTHONPATH": path}}


@contextlib.contextmanager
def _signals_deferred(ray):
    """Ctrl-C and SIGTERM held back while ``ray.init`` starts Ray's processes, then acted on.

    Interrupted half-way, ``ray.init`` leaves processes that ``ray.shutdown`` does not know of (the audit found
    a dashboard and a runtime-env agent orphaned, and their temporary folders). Here a signal that arrives
    during the start is recorded and re-delivered to the command's own handler (a KeyboardInterrupt,
    :func:`softpvtol_gym.baselines.util.args.run_main`) once Ray is up, so that the shutdown in :func:`start_ray`
    stops a complete instance. Ray's own SIGTERM handler (``sys.exit`` from inside ``ray.init``) is not installed
    meanwhile. Only in the main thread (elsewhere signals cannot be handled, and nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    own = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    received: list[int] = []

    def record(signum, frame):
        received.append(signum)

    utils = getattr(getattr(ray, "_private", None), "utils", None)
    ray_setter = getattr(utils, "set_sigterm_handler", None)
    for sig in own:
        signal.signal(sig, record)
    if ray_setter is not None:
        utils.set_sigterm_handler = lambda handler: None
    try:
        yield
    finally:
        if ray_setter is not None:
            utils.set_sigterm_handler = ray_setter
        for sig, handler in own.items():
            signal.signal(sig, handler)
    if received:
        handler = own[received[0]]
        if callable(handler):
            handler(received[0], None)
        elif received[0] == signal.SIGINT:
            raise KeyboardInterrupt()
        else:
            os.kill(os.getpid(), received[0])


@contextlib.contextmanager
def start_ray(address: str | None = None, num_cpus: int | None = None, num_gpus: int | None = None):
    """Start a local Ray instance (``address=None``: ``num_cpus`` CPUs, default all; no dashboard; a fresh
    temporary directory, removed afterwards) or connect to the cluster at ``address`` (``"auto"``: the one
    started on this machine with ``ray start``). Shut down (or disconnect) on exit. Yields the cluster's
    resources (``ray.cluster_resources()``)."""
    import ray

    if ray.is_initialized():
        raise ConfigError("Ray is already initialised in this process; call ray.shutdown() first")
    temp_dir = None
    # log_to_driver: what a task prints (warnings of a resumed run, say) reaches this terminal, as with the pool
    kwargs = dict(runtime_env=runtime_env(), log_to_driver=True, configure_logging=False)
    if address is None:
        temp_dir = _short_temp_dir()
        kwargs.update(num_cpus=num_cpus, num_gpus=num_gpus, include_dashboard=False, _temp_dir=temp_dir)
    else:
        if num_cpus is not None or num_gpus is not None:
            raise ConfigError("the CPUs and GPUs of an existing Ray cluster are set by its `ray start` commands, not "
                              "by the driver (leave out --workers with --address)")
        kwargs.update(address=address)
    try:
        with _signals_deferred(ray):
            try:
                ray.init(**kwargs)
            except ConnectionError as exc:
                raise ConfigError(f"cannot connect to a Ray cluster at {address!r}: {' '.join(str(exc).split())} "
                                  f"(start one with `ray start --head`, or leave out --address for a local instance)"
                                  ) from None
        yield ray.cluster_resources()
    finally:
        # unconditionally: interrupted inside ray.init, Ray may have started its processes without being
        # "initialised" yet, and shutdown() is what stops them (no orphan raylet or workers)
        with contextlib.suppress(Exception):
            ray.shutdown()
        if temp_dir is not None:
            shutil.rmtree(temp_dir, ignore_errors=True)


def _unwrap(exc: BaseException) -> BaseException:
    """The exception a task raised, from Ray's wrapper (``RayTaskError.cause``)."""
    from ray.exceptions import RayTaskError

    if isinstance(exc, RayTaskError) and isinstance(getattr(exc, "cause", None), BaseException):
        return exc.cause
    return exc


class RayExecutor:
    """``submit(fn, *args)`` runs ``fn(*args)`` as a Ray task (``num_cpus`` CPUs, ``num_gpus`` GPUs) and
    returns a ``concurrent.futures.Future`` whose exception, if any, is the one the task raised (not
    Ray's wrapper). Needs a running Ray (:func:`start_ray`). ``fn`` must be importable on the workers (a
    module-level function)."""

    def __init__(self, num_cpus: float = 1, num_gpus: float = 0):
        import ray

        if not ray.is_initialized():
            raise ConfigError("RayExecutor needs a running Ray (softpvtol_gym.baselines.leaderboard.ray_executor."
                              "start_ray)")
        self._ray = ray
        self._options = {"num_cpus": num_cpus, "num_gpus": num_gpus, "max_retries": 0}
        self._remote = {}

    def submit(self, fn, *args, **kwargs) -> Future:
        remote = self._remote.get(fn)
        if remote is None:
            remote = self._remote[fn] = self._ray.remote(fn).options(**self._options)
        ray_future = remote.remote(*args, **kwargs).future()
        out: Future = Future()

        def relay(done: Future) -> None:
            exc = done.exception()
            if exc is None:
                out.set_result(done.result())
            else:
                out.set_exception(_unwrap(exc))

        ray_future.add_done_callback(relay)
        return out

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:  # Executor interface
        pass

    def __enter__(self) -> RayExecutor:
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()
