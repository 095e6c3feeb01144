"""Warnings a caller can act on, shown in scripts and notebooks without any logging set-up.

The package logs through :mod:`logging` (a ``NullHandler`` by default: nothing is printed
unless the application configures logging). A doubtful result the caller should act on (a
suspect map, detail added on top of detail, parts of a shape left out) is issued as an
:class:`OFPWarning` with :func:`warnings.warn`, which Python shows by default (at every
doubtful call), and logged at DEBUG only, so that a notebook with logging at INFO (to see the
long stages) shows each warning once. ``logging.captureWarnings(True)`` sends the
warnings to the log. The command line, which prints the log and silences the warnings,
logs them at WARNING (:func:`warnings_logged`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import warnings
from collections.abc import Iterator

from .wording import Said, named

__all__ = ["OFPWarning", "about", "collected_warnings", "reissue", "warn", "warnings_logged"]

_COLLECTING = threading.local()


class OFPWarning(UserWarning):
    """A doubtful result of o3d_ofp that the caller can act on (the message names the fix)."""


# Shown at every doubtful call, not once per line of the library: a notebook cell run again
# on the same mistake must say it again (Python's default shows a warning once per place).
# Appended: the caller's own filters (e.g. "ignore", or pytest's) still come first.
warnings.filterwarnings("always", category=OFPWarning, append=True)


class _LogLevel:
    """The level :func:`warn` logs at (process-wide: a forked side process inherits it)."""

    level = logging.DEBUG


_LOG = _LogLevel()


@contextlib.contextmanager
def warnings_logged(level: int = logging.WARNING) -> Iterator[None]:
    """Log what :func:`warn` says at ``level`` while the block runs (the command line's log)."""
    before, _LOG.level = _LOG.level, level
    try:
        yield
    finally:
        _LOG.level = before


def warn(logger: logging.Logger, message: str | Said, *, stacklevel: int | None = None) -> None:
    """Issue ``message`` as an :class:`OFPWarning` and log it on ``logger`` (at DEBUG).

    The warning is attributed to the caller's own line: the first frame outside the package;
    ``stacklevel`` overrides it. The log record is at DEBUG, or at the level
    :func:`warnings_logged` sets; a :class:`~o3d_ofp.core.wording.Said` rides on it as
    ``record.said`` (a front end words it for its reader).
    """
    _collect(message)  # (a collection's record is named already)
    subject = getattr(_COLLECTING, "subject", None)
    if subject is not None:
        message = named(subject, message)
    extra = {"said": message} if isinstance(message, Said) else None
    logger.log(_LOG.level, "%s", message, extra=extra)
    if stacklevel is None:
        stacklevel = outside_the_package()
    warnings.warn(str(message), OFPWarning, stacklevel=stacklevel)


_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep


def outside_the_package() -> int:
    """``stacklevel`` (for the function that calls this) of the first frame not o3d_ofp's.

    A frame is the package's when its file is, or its globals are (the ``__init__`` that
    :mod:`dataclasses` generates for an options object).
    """
    frame = sys._getframe(2)  # the caller's caller
    level = 2
    while frame is not None and (
        os.path.abspath(frame.f_code.co_filename).startswith(_PACKAGE)
        or str(frame.f_globals.get("__name__", "")).startswith("o3d_ofp.")
    ):
        frame = frame.f_back
        level += 1
    return level


@contextlib.contextmanager
def about(name: str) -> Iterator[None]:
    """Name ``name`` (a shape's, one of several) in what :func:`warn` says in this thread."""
    before, _COLLECTING.subject = getattr(_COLLECTING, "subject", None), name
    try:
        yield
    finally:
        _COLLECTING.subject = before


def _collect(message: str | Said) -> None:
    """Add ``message`` to every :func:`collected_warnings` block open in this thread."""
    for messages in getattr(_COLLECTING, "lists", ()):
        messages.append(message)


@contextlib.contextmanager
def collected_warnings() -> Iterator[list[str | Said]]:
    """Collect the messages :func:`warn` issues in this thread while the block runs.

    Independent of the logging levels and of the warning filters (process-wide state that
    other threads may change): a collection's task keeps what was said of its target.
    """
    lists = getattr(_COLLECTING, "lists", None)
    if lists is None:
        lists = _COLLECTING.lists = []
    messages: list[str | Said] = []
    lists.append(messages)
    try:
        yield messages
    finally:
        lists.remove(messages)


def reissue(message: str, category: type[Warning]) -> None:
    """Issue here a warning another process issued (its log record was forwarded already).

    An :class:`OFPWarning` is also collected (:func:`collected_warnings`) as :func:`warn`
    does; the warning points at the caller's own line.
    """
    if issubclass(category, OFPWarning):
        _collect(message)
    warnings.warn(message, category, stacklevel=outside_the_package())
