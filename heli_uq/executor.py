"""Independent tasks (candidate fits, SBC replicates, records of a study) on Dask.

:func:`run_tasks` maps a top-level function over named arguments and returns every
task's result or the reason it failed; one failed task never aborts the others.

Schedulers
----------
``"local"`` (default)
    A ``dask.distributed.LocalCluster`` of worker *processes*, one thread each, started
    with ``spawn``: a process that has already imported JAX is never forked (forking a
    running XLA runtime can deadlock).  Workers share the JAX compilation cache of
    :func:`use_compilation_cache` (``~/.cache/heli_uq/jax`` unless :data:`CACHE_ENV` or
    this process's JAX names another), so a program compiled by one worker or an earlier
    run is not compiled again.
``"serial"``
    In this process, one task after another (tests, debugging, one-core machines).
an address (``tcp://host:8786``)
    An existing Dask scheduler (``Client(address)``); its workers must have ``heli_uq``.
    An address where nothing answers within :data:`CONNECT_TIMEOUT` is a
    :class:`~heli_uq.errors.ParameterError`.

The package's warnings (logger ``heli_uq``) that a task logs in a worker process come back
with its result and are logged here, each distinct message once, naming its task; a message
that more tasks gave is followed at the end by one line naming them (eleven candidate fits
nesting one stiff base model gave the same 500-character warning eleven times).  In this
process (``"serial"``) they are logged as they happen.

A task whose worker process dies (Dask gives up on it after its retries) becomes a
:class:`TaskFailed` like a task that raised; the others go on.  Closing a ``LocalCluster``
that :func:`run_tasks` started makes Dask log two messages that say nothing about the
run, and both are dropped.  The workers drop the record with a traceback that Dask logs
when a heartbeat races the close (:data:`HEARTBEAT_RACE`): the scheduler goes away only
because :func:`run_tasks` closes it.  This process drops the nanny's warning that a worker
process still alive after 4 s is killed (:data:`NANNY_KILL`): by then its tasks are done.

Layer 0: imports only :mod:`heli_uq.errors` (layer 0) and, when called, JAX and Dask.
"""

from __future__ import annotations

import logging
import os
import pathlib
import traceback
from collections.abc import Callable, Mapping

__all__ = ["run_tasks", "check_scheduler", "TaskFailed", "CACHE_ENV", "MIN_COMPILE_ENV",
           "MIN_COMPILE_SECONDS", "default_workers", "use_compilation_cache"]

#: Environment variable (read by JAX) naming the persistent compilation cache directory.
CACHE_ENV = "JAX_COMPILATION_CACHE_DIR"
#: Environment variable (read by JAX): programs that compiled faster than this many seconds
#: are not written to the cache.  JAX's default, 1 s, leaves out most of this package's
#: programs (thousands, most under a second each, which a rerun compiles again):
#: :func:`use_compilation_cache` sets :data:`MIN_COMPILE_SECONDS` unless the user set it.
MIN_COMPILE_ENV = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"
#: Seconds of compilation from which a program is cached: every program.  Measured by
#: ``studies/bench_cache.py`` on a second record of the length of the first: ``heli-uq
#: sample`` (1 s record) 18.5 s at JAX's 1 s, 14.5 s at 0 (153 entries, not 4); ``discover``
#: (30 s record, quick budget) 49.1 s and 35.7 s; the first runs take the same time.
MIN_COMPILE_SECONDS = 0.0
#: JAX's own default of that minimum [s]: a process whose JAX has another value set it.
JAX_DEFAULT_MIN_COMPILE_SECONDS = 1.0
#: How long :func:`run_tasks` tries to reach a scheduler given by its address.
CONNECT_TIMEOUT = "10s"
#: Start of the message (logger ``distributed.worker``, with a traceback) of a worker
#: whose heartbeat meets a scheduler that is closing.
HEARTBEAT_RACE = "Failed to communicate with scheduler during heartbeat"
#: Start of the warning (logger ``distributed.nanny``) when a worker process is still alive
#: 4 s after its nanny asked it to stop, and is killed.  JAX workers on a loaded machine
#: take that long to exit: seen on a 2-core machine while a second run shared the cores.
NANNY_KILL = "Worker process still alive after"
#: The logger whose warnings a worker's task sends back (the package's, :mod:`heli_uq.log`).
PACKAGE_LOGGER = "heli_uq"
#: Characters of a repeated warning quoted in the line that names the other tasks.
WARNING_HEAD = 60


class ClosingFilter(logging.Filter):
    """Drops the records whose message starts with ``prefix``: a message Dask logs only
    because :func:`run_tasks` closes a cluster it owns (:data:`HEARTBEAT_RACE`,
    :data:`NANNY_KILL`)."""

    def __init__(self, prefix: str):
        super().__init__()
        self.prefix = prefix

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(self.prefix)


def _quiet_closing_race() -> None:
    """Install a :class:`ClosingFilter` of :data:`HEARTBEAT_RACE` once on this process's
    ``distributed.worker`` logger (run in the workers)."""
    logger = logging.getLogger("distributed.worker")
    if not any(isinstance(f, ClosingFilter) and f.prefix == HEARTBEAT_RACE for f in logger.filters):
        logger.addFilter(ClosingFilter(HEARTBEAT_RACE))


def _close_quietly(cluster) -> None:
    """Close a cluster :func:`run_tasks` started, without the :data:`NANNY_KILL` warning of a
    worker process that takes longer to exit than Dask waits (its tasks are done or given
    up by then; the filter is on this process's ``distributed.nanny`` logger while it
    closes, and removed after)."""
    logger = logging.getLogger("distributed.nanny")
    quiet = ClosingFilter(NANNY_KILL)
    logger.addFilter(quiet)
    try:
        cluster.close()
    finally:
        logger.removeFilter(quiet)


class TaskFailed(dict):
    """The result of a task that raised: ``{"error": "<Type>: <message>"}``."""


def default_workers(n_tasks: int) -> int:
    """One worker per core, at most one per task."""
    return max(1, min(os.cpu_count() or 1, n_tasks))


def _guarded(fn: Callable, arg):
    """Run ``fn(arg)``; an exception becomes a :class:`TaskFailed` (so it crosses processes
    as data and never cancels the other tasks)."""
    try:
        return fn(arg)
    except Exception as exc:  # noqa: BLE001 - reported per task, by design
        last = traceback.extract_tb(exc.__traceback__)[-1:] or [None]
        where = f" (at {pathlib.Path(last[0].filename).name}:{last[0].lineno})" if last[0] else ""
        return TaskFailed(error=f"{type(exc).__name__}: {exc}{where}")


class _Caught(logging.Handler):
    """Keeps the package's warnings of one task as ``(logger name, level, message)``."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.records: list[tuple[str, int, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append((record.name, record.levelno, record.getMessage()))


def _guarded_in_worker(fn: Callable, arg):
    """``(_guarded(fn, arg), warnings)``, the package's warnings of the task kept
    (:class:`_Caught`) instead of written to the worker's stderr."""
    logger = logging.getLogger(PACKAGE_LOGGER)
    caught = _Caught()
    logger.addHandler(caught)
    try:
        return _guarded(fn, arg), caught.records
    finally:
        logger.removeHandler(caught)


class _Warnings:
    """The tasks' warnings, logged once each in this process (module docstring)."""

    def __init__(self):
        self.tasks: dict[str, list[str]] = {}

    def report(self, key, records) -> None:
        for name, level, message in records:
            tasks = self.tasks.setdefault(message, [])
            if not tasks:
                logging.getLogger(name).log(level, f"{message} (task {key})")
            if str(key) not in tasks:  # a task that gave it twice (a MAP refitted from itself)
                tasks.append(str(key))

    def close(self) -> None:
        for message, tasks in self.tasks.items():
            if len(tasks) > 1:
                logging.getLogger(__name__).warning(
                    f"{len(tasks) - 1} more task(s) gave the warning of task {tasks[0]} "
                    f"(\"{_head(message)}\"): {', '.join(tasks[1:])}")  # fmt: skip


def _head(message: str) -> str:
    """The first :data:`WARNING_HEAD` characters of ``message``, "..." marking a cut."""
    return message if len(message) <= WARNING_HEAD else f"{message[:WARNING_HEAD]}..."


def use_compilation_cache() -> str:
    """Keep compiled XLA programs on disk, for this process and the workers it starts.

    The directory is, in this order: :data:`CACHE_ENV` if set, the one this process's JAX
    already uses, or ``~/.cache/heli_uq/jax``.  It is exported in :data:`CACHE_ENV` (spawned
    workers read it) and, if JAX has none yet, set for this process too, so a program that
    an earlier run or another worker compiled is read instead of compiled again (entries are
    keyed by the program, the JAX version and the flags).  Programs are kept however fast
    they compiled (:data:`MIN_COMPILE_SECONDS`, exported in :data:`MIN_COMPILE_ENV`) unless
    that variable is set or this process's JAX already has a value other than its default
    (1 s).  Returns the directory.
    """
    import jax

    configured = jax.config.jax_compilation_cache_dir
    path = os.environ.get(CACHE_ENV) or configured or str(pathlib.Path.home() / ".cache" / "heli_uq" / "jax")
    pathlib.Path(path).mkdir(parents=True, exist_ok=True)
    os.environ[CACHE_ENV] = path
    if not configured:
        jax.config.update("jax_compilation_cache_dir", path)
    # a value set in the environment, or in this process's JAX (not its default), is kept
    unset = jax.config.jax_persistent_cache_min_compile_time_secs == JAX_DEFAULT_MIN_COMPILE_SECONDS
    if MIN_COMPILE_ENV not in os.environ and unset:
        os.environ[MIN_COMPILE_ENV] = repr(MIN_COMPILE_SECONDS)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return path


def _connect(address: str):
    """A client of the Dask scheduler at ``address``, or one clear error within
    :data:`CONNECT_TIMEOUT` (instead of a long hang)."""
    from dask.distributed import Client

    from heli_uq.errors import ParameterError

    try:
        return Client(address, timeout=CONNECT_TIMEOUT)
    except (OSError, TimeoutError, ValueError, MemoryError) as exc:
        # MemoryError: something that is not a Dask scheduler answered (its reply was read
        # as a frame length of exabytes).
        raise ParameterError(f"scheduler: cannot reach a Dask scheduler at {address!r} within "
                             f"{CONNECT_TIMEOUT} ({type(exc).__name__}: {exc}); expected 'local', "
                             "'serial' or the address of a running scheduler") from None  # fmt: skip


def check_scheduler(scheduler: str | None) -> None:
    """Refuse, before any work starts, a scheduler address where no Dask scheduler answers
    (:class:`~heli_uq.errors.ParameterError`, one line); ``"local"``, ``"serial"`` and
    ``None`` need no check."""
    if scheduler in (None, "local", "serial"):
        return
    _connect(scheduler).close()


def _local_cluster(cluster_class, workers: int):
    """A ``LocalCluster`` of ``workers`` spawned processes, or a
    :class:`~heli_uq.errors.ParameterError` saying why its workers did not start."""
    from heli_uq.errors import ParameterError

    try:
        return cluster_class(n_workers=workers, threads_per_worker=1, processes=True,
                             dashboard_address=":0")  # fmt: skip
    except RuntimeError as exc:  # e.g. "Nanny failed to start."
        raise ParameterError(
            f"scheduler 'local': the Dask worker processes did not start ({exc}); a script that "
            "makes this call must do so under `if __name__ == \"__main__\":` (each worker is a "
            "new Python process that imports the script), else pass scheduler=\"serial\"") from None


def run_tasks(fn: Callable, tasks: Mapping, *, scheduler: str | None = "local", workers: int | None = None,
              on_result: Callable | None = None) -> dict:  # fmt: skip
    """``{key: fn(arg)}`` for ``tasks = {key: arg}``, each task independent.

    Parameters
    ----------
    fn : callable
        A module-level function (picklable), ``fn(arg) -> result`` (picklable).
    tasks : mapping
        Task key -> argument.  Keys are returned in the same order.
    scheduler : {"local", "serial"} or str
        See the module docstring; ``None`` means ``"local"``.
    workers : int, optional
        Worker processes of the local cluster (default :func:`default_workers`).
    on_result : callable, optional
        ``on_result(key, result)``, called in this process as each task finishes (e.g. to
        save it, so an interrupted run can reuse it).

    Returns
    -------
    dict
        ``{key: result}``; a task that raised, or whose worker died, gives a
        :class:`TaskFailed`.

    Raises
    ------
    heli_uq.errors.ParameterError
        ``scheduler`` is an address where no scheduler answers within :data:`CONNECT_TIMEOUT`,
        or the local cluster's workers do not start (a script that calls this outside
        ``if __name__ == "__main__":``).
    """
    keys = list(tasks)
    results = {}

    def finish(key, result):
        results[key] = result
        if on_result is not None:
            on_result(key, result)

    if not keys:
        return {}
    if scheduler == "serial":
        for key in keys:
            finish(key, _guarded(fn, tasks[key]))
        return {k: results[k] for k in keys}

    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    use_compilation_cache()
    with dask.config.set({"distributed.worker.multiprocessing-method": "spawn",
                          "distributed.worker.daemon": False}):  # fmt: skip
        if scheduler in (None, "local"):
            cluster = _local_cluster(LocalCluster, workers or default_workers(len(keys)))
            client = Client(cluster)
            client.run(_quiet_closing_race)
        else:
            cluster, client = None, _connect(scheduler)
        warned = _Warnings()
        try:
            futures = {client.submit(_guarded_in_worker, fn, tasks[k], key=f"heli_uq-{k}-{os.getpid()}",
                                     pure=False): k for k in keys}  # fmt: skip
            for future in as_completed(futures):
                try:
                    result, records = future.result()
                except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: its worker died
                    result, records = TaskFailed(error=f"{type(exc).__name__}: {exc}"), []
                warned.report(futures[future], records)
                finish(futures[future], result)
        finally:
            warned.close()
            client.close()
            if cluster is not None:
                _close_quietly(cluster)
    return {k: results[k] for k in keys}
