"""Silencing Open3D's console warnings safely from several threads at once.

Open3D's verbosity level is one process-wide setting, and its ``VerbosityContextManager``
saves and restores it without coordination: two threads that enter and leave interleaved (a
Dask worker runs several) leave it wrong, e.g. the second one to enter saves ``Error`` and
restores it after the first one has already put back ``Info``. :func:`open3d_errors_only`
counts the threads inside instead: the first one in lowers the level, the last one out puts
back the level it found.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator
from typing import Any

from .convert import require_open3d

__all__ = ["open3d_errors_only"]

logger = logging.getLogger(__name__)

_lock = threading.Lock()
_depth = 0
_saved: Any = None


@contextlib.contextmanager
def open3d_errors_only() -> Iterator[None]:
    """Lower Open3D's console output to errors for the duration of the block (thread-safe).

    Nested and concurrent uses share one lowering: the first block entered (in any thread)
    saves the current level and sets ``Error``; the last block left restores the saved level.
    A level the caller sets with ``open3d.utility.set_verbosity_level`` while some thread is
    inside such a block is replaced when the last block is left.
    """
    global _depth, _saved
    utility = require_open3d().utility
    with _lock:
        if _depth == 0:
            _saved = utility.get_verbosity_level()
            utility.set_verbosity_level(utility.VerbosityLevel.Error)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                utility.set_verbosity_level(_saved)
                _saved = None
