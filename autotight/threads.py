"""BLAS threading.  Our matrices are small; OpenBLAS threads on a busy machine spin and can be
100× slower than one thread, so heavy entry points run with one BLAS thread per process."""

from __future__ import annotations

import functools
from typing import Any, Callable, TypeVar

from threadpoolctl import threadpool_limits

F = TypeVar("F", bound=Callable[..., Any])


def single_blas_thread(fn: F) -> F:
    """Run ``fn`` with BLAS limited to one thread (restored afterwards)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
