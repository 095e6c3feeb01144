"""Slow, obvious reference implementations the fast code is tested against."""

from __future__ import annotations

import itertools

import numpy as np


def gram_schmidt_loop(B: np.ndarray, mass: np.ndarray, tol: float):
    """Column-by-column modified Gram-Schmidt, applied twice, with the relative drop test.

    Returns (Q, kept): Q (n, q) M-orthonormal, kept the indices of the kept columns.
    """
    kept, qs = [], []
    for j in range(B.shape[1]):
        b = B[:, j].astype(np.float64)
        norm0 = np.sqrt(b @ (mass * b))
        v = b.copy()
        for _ in range(2):
            for q in qs:
                v -= (q @ (mass * v)) * q
        res = np.sqrt(v @ (mass * v))
        if norm0 == 0 or res < tol * norm0:
            continue
        qs.append(v / res)
        kept.append(j)
    Q = np.stack(qs, axis=1) if qs else np.zeros((B.shape[0], 0))
    return Q, np.asarray(kept)


def eigenproducts_naive(evecs: np.ndarray, order: int):
    """Every product by explicit enumeration (graded lex) and np.prod."""
    k = evecs.shape[1] - 1
    cols, idx = [evecs[:, 0]], [()]
    for degree in range(1, order + 1):
        for tup in itertools.combinations_with_replacement(range(1, k + 1), degree):
            cols.append(np.prod(evecs[:, list(tup)], axis=1))
            idx.append(tup)
    return np.stack(cols, axis=1), idx


def projector(Q: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """M-orthogonal projector Q Qᵀ M as a dense matrix (small n only)."""
    return Q @ (Q.T * mass[None, :])
