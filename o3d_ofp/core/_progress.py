"""Progress of a long loop, logged at INFO at most every few seconds (nothing for short ones).

The command line prints the log; a library caller sees it with ``logging.basicConfig(level=
logging.INFO)``. Loops that end within :data:`PROGRESS_SECONDS` say nothing.
"""

from __future__ import annotations

import logging
import time

__all__ = ["PROGRESS_SECONDS", "Progress", "StageProgress"]

#: A loop running longer than this many seconds logs its progress, then every as many.
PROGRESS_SECONDS = 5.0


class Progress:
    """Log ``what: done of total (percent, seconds)`` when :data:`PROGRESS_SECONDS` have passed.

    Parameters
    ----------
    logger : logging.Logger
        The calling module's logger.
    what : str
        The loop and its unit, e.g. ``"eigenbasis: n=27554 k=99: Lanczos step"``.
    total : int
        Expected count at the end (an estimate when ``about``).
    about : bool, default False
        The total is an estimate: said as "of about", the percentage capped at 99.
    """

    def __init__(self, logger: logging.Logger, what: str, total: int, *, about: bool = False):
        self.logger, self.what, self.total, self.about = logger, what, max(1, int(total)), about
        self.start = self.last = time.perf_counter()

    def __call__(self, done: int) -> None:
        """Note that ``done`` units are done; log when the interval has passed."""
        now = time.perf_counter()
        if now - self.last < PROGRESS_SECONDS:
            return
        self.last = now
        percent = 100 * done // self.total
        self.logger.info(
            "%s %d of %s%d (%d%%, %.0f s)",
            self.what,
            done,
            "about " if self.about else "",
            self.total,
            min(99, percent) if self.about else percent,
            now - self.start,
        )


class StageProgress:
    """A ``progress(stage, fraction_done)`` callback that logs at INFO every few seconds.

    The default of the map estimations' ``progress=``: a library caller with logging at INFO
    sees what a long estimation is doing while it runs (not one line at its end), as the
    command line's own reporter shows it; runs shorter than :data:`PROGRESS_SECONDS` say
    nothing.

    Parameters
    ----------
    logger : logging.Logger
        The calling module's logger.
    what : str
        The run, e.g. ``"partial match"``.
    """

    def __init__(self, logger: logging.Logger, what: str):
        self.logger, self.what = logger, what
        self.start = self.last = time.perf_counter()

    def __call__(self, stage: str, done: float) -> None:
        """Note that the run is at ``stage``, ``done`` (in [0, 1]) of the way; log if it is time."""
        now = time.perf_counter()
        if now - self.last < PROGRESS_SECONDS:
            return
        self.last = now
        self.logger.info(
            "%s: %s (%d%%, %.0f s)", self.what, stage, round(100 * done), now - self.start
        )
