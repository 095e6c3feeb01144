"""The eigenbases of several shapes at once: one per core (see :mod:`o3d_ofp.core._processes`).

Measured (2 cores, FAUST 093 and 087, k = 99 with CHOLMOD, one call each): 6890 vertices
0.91 s one after the other, 0.65 s side by side; 27.5k vertices 6.8 s and 4.4 s (ARPACK; by
block Lanczos, o3d_ofp.core._lanczos: 0.73 / 0.50 s and 3.2 / 2.0 s).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

from ..core._memory import basis_job_bytes
from ..core._processes import side_by_side
from ..core.spectrum import EigenBasis, eigenbasis

__all__ = [
    "SIDE_BY_SIDE_VERTICES",
    "answer_bytes",
    "eigenbases",
    "eigenbasis_bytes",
    "run_per_shape",
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
    jobs: Sequence[Callable[[], T]],
    vertices: Sequence[int],
    memory: Sequence[float],
    *,
    what: str,
) -> list[T]:
    """Run one job per shape, side by side when the shapes are large enough.

    Parameters
    ----------
    jobs : sequence of callables without arguments
        One per shape, independent (see :func:`o3d_ofp.core._processes.side_by_side`).
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


def eigenbases(
    shapes: Sequence[tuple[np.ndarray, np.ndarray | None, int]], **options: Any
) -> list[EigenBasis]:
    """:func:`o3d_ofp.eigenbasis` of every ``(vertices, faces, k)``, side by side.

    Parameters
    ----------
    shapes : sequence of ((n, 3) ndarray, (m, 3) ndarray or None, int)
        Each shape and its ``k``.
    **options
        Keyword options of :func:`o3d_ofp.eigenbasis` shared by all (``clamp_k``,
        ``components``, ...).

    Returns
    -------
    list of EigenBasis
        In the order of ``shapes``.
    """
    jobs = [functools.partial(eigenbasis, V, F, k=k, **options) for V, F, k in shapes]
    try:
        sizes = [(int(np.shape(V)[0]), int(k)) for V, _, k in shapes]
    except (TypeError, ValueError, IndexError):  # eigenbasis names what is wrong
        return [job() for job in jobs]
    return run_per_shape(
        jobs,
        [n for n, _ in sizes],
        [eigenbasis_bytes(n, k) for n, k in sizes],
        what="eigenbases",
    )
