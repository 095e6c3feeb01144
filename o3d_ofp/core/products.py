"""Eigenproducts: pointwise products of eigenfunctions up to a given order.

Candidates are enumerated in graded-lexicographic order: the constant ``φ0``, then
``φ1 .. φk``, then all ``φi φj`` with ``1 <= i <= j <= k``, then all ``φi φj φl`` with
``i <= j <= l``, ... There are ``C(k + N, N)`` of them for order ``N``. Each candidate is
identified by its index tuple (``()`` for the constant, ``(i,)``, ``(i, j)``, ...; indices are
the columns of :attr:`EigenBasis.evecs`, 1-based for the non-constant eigenfunctions because
column 0 is the constant). Columns are computed block by block from their index tuples, so
no ``k^N`` tensor and, with :func:`eigenproduct_blocks`, not even the whole candidate matrix
is ever held in memory.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from ._validation import check_int

__all__ = [
    "eigenproduct_blocks",
    "eigenproduct_indices",
    "eigenproducts",
    "n_eigenproducts",
]


def n_eigenproducts(k: int, order: int) -> int:
    """Count the eigenproducts of order ``<= order`` of ``k`` eigenfunctions, ``C(k+order, order)``.

    Parameters
    ----------
    k : int
        Number of non-constant eigenfunctions.
    order : int
        Maximum product order.

    Returns
    -------
    int
        The number of candidates, the constant included.

    Examples
    --------
    >>> import o3d_ofp as ofp
    >>> ofp.n_eigenproducts(3, 2)  # the constant, φ1..φ3 and their 6 products
    10
    >>> ofp.n_eigenproducts(29, 2)  # the paper's K = 30 at order 2
    465
    """
    return math.comb(k + order, order)


def eigenproduct_indices(k: int, order: int) -> list[tuple[int, ...]]:
    """Index tuples of all eigenproducts of order ``<= order``, in graded-lexicographic order.

    Parameters
    ----------
    k : int
        Number of non-constant eigenfunctions (indices ``1..k``).
    order : int
        Maximum product order ``N >= 1``.

    Returns
    -------
    list of tuple of int
        ``C(k + N, N)`` tuples: ``()`` (the constant), ``(1,) .. (k,)``, ``(1, 1), (1, 2), ...``.

    Examples
    --------
    >>> import o3d_ofp as ofp
    >>> ofp.eigenproduct_indices(2, 2)
    [(), (1,), (2,), (1, 1), (1, 2), (2, 2)]
    >>> len(ofp.eigenproduct_indices(29, 2)) == ofp.n_eigenproducts(29, 2)
    True
    """
    k = check_int(k, name="k", minimum=1)
    order = check_int(order, name="order", minimum=1)
    out: list[tuple[int, ...]] = []
    for degree in range(order + 1):
        out.extend(itertools.combinations_with_replacement(range(1, k + 1), degree))
    return out


def _as_evecs(evecs: Any) -> np.ndarray:
    arr = np.asarray(evecs, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise ValueError(f"evecs must have shape (n, k+1) with k >= 1; got {arr.shape}")
    return arr


def eigenproduct_blocks(
    evecs: Any, order: int, *, block_size: int = 256
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield the candidate matrix in column blocks.

    Parameters
    ----------
    evecs : (n, k+1) array_like of float
        Eigenfunctions with the constant in column 0 (as in :class:`EigenBasis`).
    order : int
        Maximum product order ``N >= 1``.
    block_size : int, default 256
        Number of columns per block.

    Yields
    ------
    start : int
        Index of the block's first candidate.
    block : (n, b) ndarray of float64
        Candidates ``start .. start + b - 1`` (a new array each time).
    """
    phi = _as_evecs(evecs)
    order = check_int(order, name="order", minimum=1)
    block_size = check_int(block_size, name="block_size", minimum=1)
    k = phi.shape[1] - 1
    indices = eigenproduct_indices(k, order)
    # Column-major factors: every candidate column is a product of contiguous columns.
    factors = np.asfortranarray(phi)
    for start in range(0, len(indices), block_size):
        stop = min(start + block_size, len(indices))
        block = np.empty((phi.shape[0], stop - start), order="F")
        for col, tup in enumerate(indices[start:stop]):
            if len(tup) == 0:
                block[:, col] = factors[:, 0]
            elif len(tup) == 1:
                block[:, col] = factors[:, tup[0]]
            else:
                np.multiply(factors[:, tup[0]], factors[:, tup[1]], out=block[:, col])
                for i in tup[2:]:
                    block[:, col] *= factors[:, i]
        yield start, block


def eigenproducts(evecs: Any, order: int) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """All eigenproducts of order ``<= order`` as one matrix.

    Parameters
    ----------
    evecs : (n, k+1) array_like of float
        Eigenfunctions with the constant in column 0.
    order : int
        Maximum product order ``N >= 1``.

    Returns
    -------
    products : (n, C(k+N, N)) ndarray of float64
        The candidates in graded-lexicographic order; column 0 is ``φ0``.
    indices : list of tuple of int
        The index tuple of every column (see :func:`eigenproduct_indices`).

    References
    ----------
    .. [1] F. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021, Sec. 2 (Def. 2.1) and 3.3.
       doi:10.1111/cgf.142645

    Examples
    --------
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> eig = ofp.eigenbasis(sphere, k=3)
    >>> P, indices = ofp.eigenproducts(eig.evecs, 2)
    >>> P.shape
    (182, 10)
    >>> indices[:6]
    [(), (1,), (2,), (3,), (1, 1), (1, 2)]
    """
    phi = _as_evecs(evecs)
    order = check_int(order, name="order", minimum=1)
    k = phi.shape[1] - 1
    total = n_eigenproducts(k, order)
    out = np.empty((phi.shape[0], total), order="F")
    for start, block in eigenproduct_blocks(phi, order):
        out[:, start : start + block.shape[1]] = block
    return out, eigenproduct_indices(k, order)
