"""Progress bars on a terminal (tqdm); nothing when stderr is not a terminal or with ``-q``."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator

__all__ = ["ENABLED", "stage_progress"]


class _Switch:
    """Whether bars are drawn (set by ``main`` from ``-q`` and the terminal)."""

    on = False


ENABLED = _Switch()


@contextlib.contextmanager
def stage_progress(title: str) -> Iterator[Callable[[str, float], None]]:
    """Yield ``progress(stage, fraction_done)`` that moves a bar of 100 steps on stderr."""
    if not (ENABLED.on and sys.stderr.isatty()):
        yield lambda stage, done: None
        return
    from tqdm import tqdm

    with tqdm(total=100, desc=title, file=sys.stderr, leave=False, unit="%") as bar:

        def progress(stage: str, done: float) -> None:
            bar.set_postfix_str(stage)
            bar.update(max(0, round(100 * done) - bar.n))

        yield progress
