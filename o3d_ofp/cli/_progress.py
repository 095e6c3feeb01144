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
import types
from collections.abc import Callable, Iterator

from ..core import _progress

logger = logging.getLogger(__name__)


#: Whether progress is shown (``on``, set by ``main`` from ``-q``).
ENABLED = types.SimpleNamespace(on=False)


@contextlib.contextmanager
def stage_progress(title: str) -> Iterator[Callable[[str, float], None]]:
    """Yield ``progress(stage, fraction_done)``: a bar on a terminal, log lines otherwise."""
    if not ENABLED.on:
        yield lambda stage, done: None
        return
    if not sys.stderr.isatty():  # the library's own reporter (what a Python caller sees)
        yield _progress.StageProgress(logger, title)
        return
    from tqdm import tqdm

    with tqdm(total=100, desc=title, file=sys.stderr, leave=False, unit="%") as bar:

        def progress(stage: str, done: float) -> None:
            bar.set_postfix_str(stage)
            bar.update(max(0, round(100 * done) - bar.n))

        yield progress
