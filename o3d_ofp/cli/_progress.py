"""Progress of the long stages: a bar on a terminal (tqdm), log lines otherwise.

On a terminal, a tqdm bar of 100 steps on stderr. When stderr is a file or a pipe (a batch
job, CI, ``2> log``), a bar would write control characters; instead the stage and its
percentage are logged as the library's long loops log theirs (:mod:`o3d_ofp.core._progress`:
nothing for a stage done within ``PROGRESS_SECONDS``, then a line every as many seconds).
Nothing with ``-q``.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from collections.abc import Callable, Iterator

from ..core import _progress

__all__ = ["ENABLED", "stage_progress"]

logger = logging.getLogger(__name__)


class _Switch:
    """Whether progress is shown (set by ``main`` from ``-q``)."""

    on = False


ENABLED = _Switch()


@contextlib.contextmanager
def stage_progress(title: str) -> Iterator[Callable[[str, float], None]]:
    """Yield ``progress(stage, fraction_done)``: a bar on a terminal, log lines otherwise."""
    if not ENABLED.on:
        yield lambda stage, done: None
        return
    if not sys.stderr.isatty():
        start = time.perf_counter()
        last = [start]

        def log(stage: str, done: float) -> None:
            now = time.perf_counter()
            if now - last[0] >= _progress.PROGRESS_SECONDS:
                last[0] = now
                logger.info("%s: %s (%d%%, %.0f s)", title, stage, round(100 * done), now - start)

        yield log
        return
    from tqdm import tqdm

    with tqdm(total=100, desc=title, file=sys.stderr, leave=False, unit="%") as bar:

        def progress(stage: str, done: float) -> None:
            bar.set_postfix_str(stage)
            bar.update(max(0, round(100 * done) - bar.n))

        yield progress
