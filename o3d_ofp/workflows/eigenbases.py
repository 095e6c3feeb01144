"""The eigenbases of several shapes at once: one per core (see :mod:`o3d_ofp.core._processes`).

Measured (2 cores, FAUST 093 and 087, k = 99 with CHOLMOD, one call each): 6890 vertices
0.91 s one after the other, 0.65 s side by side; 27.5k vertices 6.8 s and 4.4 s (ARPACK; by
block Lanczos, o3d_ofp.core._lanczos: 0.73 / 0.50 s and 3.2 / 2.0 s).
"""

from __future__ import annotations

import contextlib
import functools
import logging
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

import numpy as np

from ..core._memory import basis_job_bytes
from ..core._processes import side_by_side
from ..core.cleaning import check_shape
from ..core.spectrum import EigenBasis, eigenbasis
from ..core.wording import AdvisedError, OptionError, Said

__all__ = [
    "SIDE_BY_SIDE_VERTICES",
    "answer_bytes",
    "check_shapes",
    "eigenbases",
    "eigenbasis_bytes",
    "run_per_shape",
    "said_of",
]

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: Shapes with fewer vertices than this are solved one after the other: a child process
#: costs ~20-50 ms to start and answer, an eigensolve of 99 eigenpairs on 2000 vertices
#: ~0.1 s.
SIDE_BY_SIDE_VERTICES = 2000


def answer_bytes(n: int, columns: int) -> float:
    """Bytes of the copies of a child's answer of ``columns`` dense columns on ``n`` vertices.

    The child holds its value and its pickle; this process the bytes received and the value
    rebuilt from them: about two copies on each side, four in all (the sparse matrices are
    small beside the columns).
    """
    return 4 * 8.0 * n * columns


def eigenbasis_bytes(n: int, k: int) -> float:
    """Estimated peak bytes of one :func:`o3d_ofp.eigenbasis` job side by side (answer included)."""
    return basis_job_bytes(n, k=1, order=1, eig_k=k) + answer_bytes(n, k + 1)


def run_per_shape(
    jobs: Sequence[Callable[[], T]], vertices: Sequence[int], memory: Sequence[float], *, what: str
) -> list[T]:
    """Run jobs on shapes (one per shape, or several on one), side by side when large enough.

    Parameters
    ----------
    jobs : sequence of callables without arguments
        Independent (see :func:`o3d_ofp.core._processes.side_by_side`).
    vertices : sequence of int
        Vertices each job works on (0: a job that only reads a file), for the threshold.
    memory : sequence of float
        Estimated peak bytes of each job, its answer's copies included.
    what : str
        What the jobs compute, for the log.

    Returns
    -------
    list
        The jobs' values, in order.
    """
    if len(jobs) < 2 or min(vertices) < SIDE_BY_SIDE_VERTICES:
        return [job() for job in jobs]
    return side_by_side(jobs, what=what, memory_each=max(memory))


def check_shapes(
    shapes: Sequence[tuple[Any, Any]], *, names: Sequence[str] | None = None,
    components: str = "auto", weld_tolerance: float | None = 1e-9,
) -> None:  # fmt: skip
    """Refuse, before any of them is solved, a shape its eigensolve would refuse.

    :func:`o3d_ofp.core.cleaning.check_shape` on each (the cleaning's cheap steps: welding,
    faces, a mesh's components policy; 0.3 s for 110k vertices, 1.3-1.7 s for 440k: FAUST
    093 subdivided, measured beside a test run, 2026-11-30), so that
    the second of two shapes with several components is refused before the first one's
    eigensolve (side by side, the error would wait for the other solve to end).

    Parameters
    ----------
    shapes : sequence of ((n, 3) array_like, (m, 3) array_like or None)
        Vertices and faces (None: a point cloud) of each shape.
    names : sequence of str, optional
        How the messages name each shape (default "shape 1 of 2", ...).
    components, weld_tolerance
        As in :func:`o3d_ofp.eigenbasis`.

    Raises
    ------
    TypeError, ValueError
        The cleaning's message, after the shape's name.
    """
    for i, (V, F) in enumerate(shapes):
        name = names[i] if names is not None else f"shape {i + 1} of {len(shapes)}"
        with said_of(name):
            check_shape(V, F, components=components, weld_tolerance=weld_tolerance)


@contextlib.contextmanager
def said_of(name: str) -> Iterator[None]:
    """Put ``name`` (a shape's) before the message of a refusal raised in the block."""
    try:
        yield
    except AdvisedError as exc:  # its fix stays data
        said = Said("{name}: {said}", {"name": name, "said": exc.said}, exc.said.code)
        raise AdvisedError(said) from exc
    except (TypeError, ValueError) as exc:
        if isinstance(exc, OptionError) or str(exc).startswith(f"{name}: "):
            raise
        raise type(exc)(f"{name}: {exc}") from exc


def eigenbases(
    shapes: Sequence[tuple[np.ndarray, np.ndarray | None, int]], *,
    names: Sequence[str] | None = None, **options: Any,
) -> list[EigenBasis]:  # fmt: skip
    """:func:`o3d_ofp.eigenbasis` of every ``(vertices, faces, k)``, side by side.

    Every shape is checked (:func:`check_shapes`) before any is solved.

    Parameters
    ----------
    shapes : sequence of ((n, 3) ndarray, (m, 3) ndarray or None, int)
        Each shape and its ``k``.
    names : sequence of str, optional
        How error messages name each shape (default "shape 1 of 2", ...).
    **options
        Keyword options of :func:`o3d_ofp.eigenbasis` shared by all (``clamp_k``,
        ``components``, ...).

    Returns
    -------
    list of EigenBasis
        In the order of ``shapes``.
    """
    if len(shapes) > 1:
        check_shapes([(V, F) for V, F, _ in shapes], names=names,
                     components=options.get("components", "auto"),
                     weld_tolerance=options.get("weld_tolerance", 1e-9))  # fmt: skip
    jobs = [functools.partial(eigenbasis, V, F, k=k, **options) for V, F, k in shapes]
    try:
        sizes = [(int(np.shape(V)[0]), int(k)) for V, _, k in shapes]
    except (TypeError, ValueError, IndexError):  # eigenbasis names what is wrong
        return [job() for job in jobs]
    memory = [eigenbasis_bytes(n, k) for n, k in sizes]
    return run_per_shape(jobs, [n for n, _ in sizes], memory, what="eigenbases")
