"""Memory estimates: refuse a request that cannot fit, with the number, before allocating."""

from __future__ import annotations

import logging

__all__ = ["available_memory", "check_memory", "format_bytes"]

logger = logging.getLogger(__name__)


def available_memory() -> int | None:
    """Bytes of memory the system can give us now (psutil's ``available``), or None if unknown."""
    try:
        import psutil
    except ImportError:  # pragma: no cover - a dependency
        return None
    try:
        return int(psutil.virtual_memory().available)
    except (OSError, RuntimeError, AttributeError):
        return None


def format_bytes(nbytes: float) -> str:
    """Human-readable size, e.g. ``'3.2 GB'``."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(nbytes) < 1000 or unit == "TB":
            return f"{nbytes:.3g} {unit}"
        nbytes /= 1000
    raise AssertionError("unreachable")


def check_memory(nbytes: float, what: str, *, limit: float | None = None) -> None:
    """Raise ``ValueError`` when ``nbytes`` exceeds ``limit`` (default: the available memory).

    Parameters
    ----------
    nbytes : float
        Estimated peak bytes of the request.
    what : str
        Description used in the message (e.g. ``"the product basis (k=60, order 3)"``).
    limit : float, optional
        Bytes allowed; default the system's available memory (no check when unknown).
    """
    if limit is None:
        limit = available_memory()
        if limit is None:
            return
    if nbytes > limit:
        raise ValueError(
            f"{what} needs about {format_bytes(nbytes)} of memory, more than the "
            f"{format_bytes(limit)} available; lower k or the order, or use a coarser mesh"
        )
    logger.debug("%s: estimated %s of %s", what, format_bytes(nbytes), format_bytes(limit))
