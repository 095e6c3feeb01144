"""Atomic file output: write to a temporary file beside the target, then rename it."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator

__all__ = ["atomic_path", "current_umask", "default_file_mode", "output_folder"]


def _umask_from_proc() -> int | None:
    """Read the umask from ``/proc/self/status`` (Linux >= 4.7); None where it is not there."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        return None
    return None


def _umask_at_import() -> int:
    # os.umask can only be read by setting it; done once, while the module is imported (under
    # the import lock), never at run time where another thread could create a file meanwhile.
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


_UMASK_AT_IMPORT = _umask_from_proc()
if _UMASK_AT_IMPORT is None:  # pragma: no cover - not Linux
    _UMASK_AT_IMPORT = _umask_at_import()


def current_umask() -> int:
    """Return the process umask, read without changing it (thread-safe).

    From ``/proc/self/status`` where the system has it (so a later ``os.umask`` call is
    seen); elsewhere the value when this module was imported.
    """
    umask = _umask_from_proc()
    return _UMASK_AT_IMPORT if umask is None else umask


def default_file_mode() -> int:
    """Permissions of a newly created file: ``0o666 & ~umask``."""
    return 0o666 & ~current_umask()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, suffix: str = "") -> Iterator[str]:
    """Yield a temporary path in ``path``'s folder; on success rename it to ``path``.

    The temporary file gets the usual permissions (``0666 & ~umask``, not mkstemp's 0600).
    On any exception it is removed and ``path`` is left as it was: a reader never sees a
    half-written file.

    Parameters
    ----------
    path : str or os.PathLike
        Final destination.
    suffix : str, optional
        Suffix of the temporary name (some writers pick the format from it).
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    stem = os.path.basename(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{stem}.", suffix=suffix, dir=folder)
    except OSError as exc:  # said of the file asked for, not of a temporary name
        raise type(exc)(exc.errno, exc.strerror, path) from None
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, default_file_mode())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


@contextlib.contextmanager
def output_folder(path: str | os.PathLike[str]) -> Iterator[str]:
    """Create the folder ``path`` (with its parents) for the outputs of a run.

    On any exception, an interrupt included, a folder this call created is removed again
    when it is still empty: a refused or interrupted run leaves no empty folder behind.
    """
    path = os.fspath(path)
    created = not os.path.isdir(path)
    os.makedirs(path, exist_ok=True)
    try:
        yield path
    except BaseException:
        if created:
            with contextlib.suppress(OSError):
                os.rmdir(path)
        raise
