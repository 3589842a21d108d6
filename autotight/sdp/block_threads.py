"""Per-block batched work of the IPM spread over worker threads.

The blocks of one size group are a (B, n, n) stack; a per-block function (every output block depends only
on the same block of the inputs: Cholesky, inverse, eigh, products) runs on contiguous slices of the
stack in worker threads and the slices' outputs are concatenated.  numpy's linalg and matmul loops call
LAPACK/BLAS once per matrix and release the GIL, so the slices run in parallel, and each block's result
is the same to the bit as the unsplit call's.  Reductions over blocks (sums) are not split here: their
rounding would depend on the split.
"""

from __future__ import annotations

import os
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable, Sequence

import numpy as np

#: a stack with fewer blocks than this runs in the calling thread (a thread's hand-off costs ~50 µs)
MIN_SPLIT_BLOCKS = 64
#: programs with less per-block work than this (Σ n_k³ over the blocks) run in one thread by default: a
#: hand-off per step would cost more than it saves
THREADED_MIN_WORK = 4e6


def threaded(sizes: Sequence[int]) -> bool:
    """Whether blocks of these sizes are worth a second thread (``THREADED_MIN_WORK``)."""
    return float(sum(float(n) ** 3 for n in sizes)) >= THREADED_MIN_WORK


def default_workers() -> int:
    """The CPUs this process may use (``os.sched_getaffinity`` where it exists), capped by ``OMP_NUM_THREADS``
    when that is set to a positive integer (parallel workers, e.g. joblib's, set it to 1), at most 2."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    omp = os.environ.get("OMP_NUM_THREADS", "").strip()
    if omp.isdigit() and int(omp) > 0:
        n = min(n, int(omp))
    return max(1, min(2, n))


class BlockThreads:
    """A pool of ``workers`` threads (1: everything runs in the calling thread).  Use as a context manager
    or call ``close``."""

    def __init__(self, workers: int | None = None):
        self.workers = default_workers() if workers is None else max(1, int(workers))
        self._pool = ThreadPoolExecutor(self.workers - 1) if self.workers > 1 else None

    def __enter__(self) -> "BlockThreads":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def submit(self, fn: Callable[..., Any], *args: Any) -> "Future[Any]":
        """fn(*args) in a worker thread (or now, without workers: a finished future); ``.result()`` gives its
        value or raises its exception."""
        if self._pool is not None:
            return self._pool.submit(fn, *args)
        done: Future[Any] = Future()
        try:
            done.set_result(fn(*args))
        except BaseException as e:  # as the pool's future would hold it
            done.set_exception(e)
        return done

    def each(self, fn: Callable[..., Any], *groups: Sequence[np.ndarray]) -> list[Any]:
        """[fn(*args) for args in zip(*groups)], each call split along axis 0 of its stacks into
        ``workers`` contiguous slices run in parallel; fn returns an array or a tuple of arrays (B, …)."""
        return [self._split(fn, args) for args in zip(*groups)]

    def _split(self, fn: Callable[..., Any], args: tuple[np.ndarray, ...]) -> Any:
        B = args[0].shape[0]
        if self._pool is None or B < MIN_SPLIT_BLOCKS:
            return fn(*args)
        cuts = np.linspace(0, B, self.workers + 1).round().astype(int)
        parts = [tuple(a[lo:hi] for a in args) for lo, hi in zip(cuts[:-1], cuts[1:])]
        futures = [self._pool.submit(fn, *p) for p in parts[1:]]
        first = fn(*parts[0])
        rest = [f.result() for f in futures]
        if isinstance(first, tuple):
            return tuple(np.concatenate(cols) for cols in zip(first, *rest))
        return np.concatenate([first, *rest])
