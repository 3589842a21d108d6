"""Where trials run: in-process, on local cores with joblib (loky), or on a Dask distributed cluster.

Every backend yields results as they complete, in the parent process, so the caller can save
each one at once.  Workers use one solver/BLAS thread each (loky: ``inner_max_num_threads=1``
sets OMP/OpenBLAS/MKL threads in the workers; the trial itself also limits BLAS to one thread).
"""

from __future__ import annotations

from typing import Any, Callable, Iterator, Sequence

from ..errors import AutotightError

RESUME = "finished trials are saved; re-run the same command to resume"


def execute(fn: Callable[..., Any], calls: Sequence[tuple], *, jobs: int = 1,
            scheduler: Any = None) -> Iterator[Any]:
    """``fn(*args)`` for every args in ``calls``, yielded in completion order.

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


def _joblib(fn: Callable[..., Any], calls: Sequence[tuple], jobs: int) -> Iterator[Any]:
    from joblib import Parallel, delayed, parallel_config
    from joblib.externals.loky.process_executor import TerminatedWorkerError

    with parallel_config(backend="loky", inner_max_num_threads=1):
        par = Parallel(n_jobs=jobs, return_as="generator_unordered", batch_size=1, pre_dispatch="2*n_jobs")
        results = par(delayed(fn)(*args) for args in calls)
    try:
        yield from results
    except TerminatedWorkerError as e:
        first = str(e).split(". ")[0].splitlines()[0] if str(e) else type(e).__name__
        raise AutotightError(f"a worker process died ({first}); {RESUME}") from e


def _dask(fn: Callable[..., Any], calls: Sequence[tuple], scheduler: Any) -> Iterator[Any]:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise AutotightError("--scheduler needs dask.distributed: pip install 'autotight[dask]'") from None
    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout=30) if own else scheduler
    except (OSError, TimeoutError, ValueError) as e:
        raise AutotightError(f"cannot reach the Dask scheduler at {scheduler!r}: {e}") from None
    futures = []
    try:
        futures = client.map(fn, *zip(*calls), pure=False) if calls else []
        for fut in as_completed(futures):
            yield fut.result()
    finally:
        if futures:
            client.cancel(futures)
        if own:
            client.close()
