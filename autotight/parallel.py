"""Where trials run: in-process, on local cores with joblib (loky), or on a Dask distributed cluster.

Every backend yields results as they complete, in the parent process, so the caller can save
each one at once.  Workers use one solver/BLAS thread each (loky: ``inner_max_num_threads=1``
sets OMP/OpenBLAS/MKL threads in the workers; the trial itself also limits BLAS to one thread).
A loky worker exits within ``WATCH_INTERVAL_S`` of its parent's death (SIGKILL, SIGTERM): a
watchdog thread started by the worker initializer polls its parent pid.  A Dask scheduler is
reached (``connect``) before any work, within ``CONNECT_TIMEOUT_S``.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from typing import Any, Callable, Iterable, Iterator

from .errors import AutotightError

RESUME = "finished trials are saved; re-run the same command to resume"
#: how often a worker checks that its parent is alive (s)
WATCH_INTERVAL_S = 0.2
#: how long reaching a Dask scheduler may take (s)
CONNECT_TIMEOUT_S = 5


def _exit_with_parent(parent: int, interval: float = WATCH_INTERVAL_S) -> None:
    """Worker initializer: a daemon thread that ends this process once ``parent`` is gone."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(interval)
        os._exit(1)

    threading.Thread(target=watch, name="autotight-parent-watchdog", daemon=True).start()


def usable_cpus() -> int:
    """The CPUs this process may run on (``os.sched_getaffinity`` where it exists, else ``os.cpu_count``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def execute(fn: Callable[..., Any], calls: Iterable[tuple], *, jobs: int = 1,
            scheduler: Any = None) -> Iterator[Any]:
    """``fn(*args)`` for every args in ``calls``, yielded in completion order.  ``calls`` is read lazily in
    process and by joblib (as workers free up), all at once by Dask.

    ``scheduler``: a Dask scheduler address (or a ``distributed.Client``); else ``jobs`` > 1 uses
    joblib's loky processes and ``jobs`` = 1 runs in this process.
    """
    if jobs < 1:
        raise AutotightError(f"--jobs {jobs}: need at least 1 worker")
    if scheduler is not None:
        return _dask(fn, calls, scheduler)
    if jobs == 1:
        return (fn(*args) for args in calls)
    return _joblib(fn, calls, jobs)


def _joblib(fn: Callable[..., Any], calls: Iterable[tuple], jobs: int) -> Iterator[Any]:
    from joblib import Parallel, delayed, parallel_config
    from joblib.externals.loky.process_executor import TerminatedWorkerError

    with parallel_config(backend="loky", inner_max_num_threads=1, initializer=_exit_with_parent,
                         initargs=(os.getpid(),)):
        par = Parallel(n_jobs=jobs, return_as="generator_unordered", batch_size=1, pre_dispatch="2*n_jobs")
        results = par(delayed(fn)(*args) for args in calls)
    try:
        yield from results
    except TerminatedWorkerError as e:
        first = str(e).split(". ")[0].splitlines()[0] if str(e) else type(e).__name__
        raise AutotightError(f"a worker process died ({first}); {RESUME}") from e


@contextlib.contextmanager
def connect(scheduler: Any) -> Iterator[Any]:
    """A ``distributed.Client`` for ``scheduler`` (an address, or a Client used as is), closed afterwards;
    None for None.  AutotightError when it cannot be reached within ``CONNECT_TIMEOUT_S``."""
    if scheduler is None:
        yield None
        return
    try:
        from distributed import Client
    except ImportError:
        raise AutotightError("--scheduler needs dask.distributed: pip install 'autotight[dask]'") from None
    if isinstance(scheduler, Client):
        yield scheduler
        return
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError, TypeError) as e:
        first = (str(e).splitlines() or [type(e).__name__])[0]
        raise AutotightError(f"cannot reach the Dask scheduler at {scheduler!r} within {CONNECT_TIMEOUT_S} s: "
                             f"{first}") from None
    try:
        yield client
    finally:
        client.close()


def _dask(fn: Callable[..., Any], calls: Iterable[tuple], scheduler: Any) -> Iterator[Any]:
    from distributed import as_completed

    calls = list(calls)
    with connect(scheduler) as client:
        futures: list[Any] = []
        try:
            futures = client.map(fn, *zip(*calls), pure=False) if calls else []
            for fut in as_completed(futures):
                yield fut.result()
        finally:
            if futures:
                client.cancel(futures)
