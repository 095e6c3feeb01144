"""BLAS thread limits around the stages where threading costs more than it gives.

Measured on the 2-core development machine (OpenBLAS, 2 threads by default), same process,
alternating runs: ZoomOut on FAUST (2000 samples, 30 → 99) 3.6 s with 2 threads vs 1.8-2.1 s
with 1; the OFP basis of a 7k-vertex shape 0.24-0.67 s vs 0.13 s; at 50k vertices no
difference; at 200k the basis is faster with 2 threads (4.7 s vs 5.6 s) and the eigensolve
is the same either way. The many small and mid-size products of the iterative stages
(Lanczos, L-BFGS-B, ZoomOut, nearest neighbours) lose to thread start-up and spinning; large
BLAS-3 blocks gain a little. The limit must wrap the call itself: a limit set before a module
is imported does not reach its BLAS.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import threading
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

__all__ = ["PARALLEL_ROWS", "blas_threads", "one_blas_thread", "single_threaded_below"]

logger = logging.getLogger(__name__)

#: Below this many rows (vertices), the dense kernels of the basis run on one BLAS thread.
PARALLEL_ROWS = 100_000


#: BLAS limits are process-wide: the calls active in every thread share one record, so that
#: interleaved calls (threads of a Dask worker) neither lift each other's limit nor leave it
#: behind. The strictest active limit applies; the last call out restores what the first found.
_LOCK = threading.Lock()
# A process forked while another thread holds the lock (it does for ~1.6 ms at each limit
# change) would inherit it held, and its first limit would wait forever: a fork waits for
# the lock, and the child starts with it free (o3d_ofp.core._processes forks).
if hasattr(os, "register_at_fork"):  # POSIX
    os.register_at_fork(
        before=_LOCK.acquire, after_in_parent=_LOCK.release, after_in_child=_LOCK.release
    )
_ACTIVE: list[int] = []
_ORIGINAL: list[Any] = []  # the threadpoolctl object of the first entrant (0 or 1 element)


def _take_control() -> None:
    """Let this thread change OpenBLAS' pool (callers hold :data:`_LOCK`).

    threadpoolctl >= 3.8 lets only one "controlling" thread change a shared OpenBLAS pool and
    silently ignores the others: without this, a limit set or restored by a second thread
    (the last one out of an interleaved pair, or any thread after the main one set a limit)
    would not happen.
    """
    from threadpoolctl import OpenBLASController

    clear = getattr(OpenBLASController, "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)


def _apply(limit: int) -> Any:
    from threadpoolctl import threadpool_limits

    _take_control()
    return threadpool_limits(limits=limit, user_api="blas")


def _restore(limiter: Any) -> None:
    _take_control()
    limiter.restore_original_limits()
    _take_control()  # released: the caller's other code may set limits again


@contextlib.contextmanager
def blas_threads(limit: int | None) -> Iterator[None]:
    """Limit BLAS (OpenBLAS, MKL, BLIS) to ``limit`` threads inside the block (None: no limit).

    Safe in threads: while several blocks are open in any threads, the smallest of their
    limits applies, and the setting found by the first one is restored when the last closes.
    A no-op when :mod:`threadpoolctl` is not installed.
    """
    if limit is None:
        yield
        return
    try:
        import threadpoolctl  # noqa: F401
    except ImportError:  # pragma: no cover - a dependency, but never required to run
        yield
        return
    limit = int(limit)
    with _LOCK:
        _ACTIVE.append(limit)
        if _ORIGINAL:
            if limit < min(_ACTIVE[:-1]):
                _apply(limit)
        else:
            _ORIGINAL.append(_apply(limit))
    try:
        yield
    finally:
        with _LOCK:
            before = min(_ACTIVE)
            _ACTIVE.remove(limit)
            if not _ACTIVE:
                _restore(_ORIGINAL.pop())
            elif min(_ACTIVE) != before:
                _apply(min(_ACTIVE))


def single_threaded_below(rows: int) -> contextlib.AbstractContextManager[None]:
    """One BLAS thread for problems with fewer than :data:`PARALLEL_ROWS` rows."""
    return blas_threads(1 if rows < PARALLEL_ROWS else None)


def one_blas_thread(fn: F) -> F:
    """Run ``fn`` with BLAS limited to one thread (for the iterative, small-matrix stages)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with blas_threads(1):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
