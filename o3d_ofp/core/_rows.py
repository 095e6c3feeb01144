"""Distinct rows of an integer array: what ``np.unique(rows, axis=0)`` returns, without its cost.

``np.unique(..., axis=0)`` sorts the rows as records, field by field, which is slow: on FAUST
093 midpoint-subdivided to 440k vertices its calls on the edges, the faces and the welded
positions took 9.3 s of one shape's dense match, where this takes under 1 s
(``scripts/bench_match.py --levels 3``, profiled). Each row becomes one int64 key instead, a
mixed-radix number whose order is the rows' lexicographic order: a column spanning few values
enters by its offset from its minimum, a column spanning many (grid cells of positions) by its
rank among its distinct values. Rows whose keys would not fit in int64 are sorted by
``np.lexsort``. Every output is the one ``np.unique(rows, axis=0, ...)`` gives (tested).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["unique_rows"]

#: Keys stay below this (a margin under int64's 2**63).
_KEY_LIMIT = 2**62


def unique_rows(
    rows: Any, *, return_index: bool = False, return_inverse: bool = False,
    return_counts: bool = False,
) -> np.ndarray | tuple[np.ndarray, ...]:  # fmt: skip
    """Return the distinct rows in lexicographic order, as ``np.unique(rows, axis=0)`` does.

    Parameters
    ----------
    rows : (n, w) array_like of int
        The rows.
    return_index : bool, default False
        Also return the first occurrence of every distinct row.
    return_inverse : bool, default False
        Also return, for every row, its distinct row's position.
    return_counts : bool, default False
        Also return how often every distinct row occurs.

    Returns
    -------
    unique : (u, w) ndarray
        The distinct rows, sorted lexicographically, in the input's dtype.
    index : (u,) ndarray of intp, optional
    inverse : (n,) ndarray of intp, optional
    counts : (u,) ndarray of intp, optional
    """
    a = np.asarray(rows)
    if a.ndim != 2 or a.dtype.kind not in "iu":
        raise TypeError(f"unique_rows takes a 2-D integer array; got shape {a.shape}, {a.dtype}")
    n, width = a.shape
    if n == 0 or width == 0 or (a.dtype.kind == "u" and a.dtype.itemsize == 8):
        return np.unique(a, axis=0, return_index=return_index, return_inverse=return_inverse,
                         return_counts=return_counts)  # fmt: skip
    digits, decode = _digits(a.astype(np.int64, copy=False))
    first = np.empty(n, dtype=bool)
    first[0] = True
    if math.prod(radix for radix, _ in decode) >= _KEY_LIMIT:
        order = np.lexsort(digits[::-1])  # stable; lexsort's last key is the primary one
        ranked = np.stack(digits, axis=1)[order]
        first[1:] = np.any(ranked[1:] != ranked[:-1], axis=1)
        unique = a[order[first]]
    else:
        key = digits[0].copy()
        for column, (radix, _) in zip(digits[1:], decode[1:], strict=True):
            key *= radix
            key += column
        if return_index or return_inverse:
            # Only the first occurrences need a stable sort (equal keys keep the input order).
            order = np.argsort(key, kind="stable" if return_index else "quicksort")
            key = key[order]
            first[1:] = key[1:] != key[:-1]
            unique = a[order[first]]
        else:  # the keys alone, sorted in place, give the rows
            key.sort()
            first[1:] = key[1:] != key[:-1]
            unique = _decoded(key[first], decode).astype(a.dtype, copy=False)
    out: list[np.ndarray] = [unique]
    if return_index:
        out.append(order[first].astype(np.intp, copy=False))
    if return_inverse:
        inverse = np.empty(n, dtype=np.intp)
        inverse[order] = np.cumsum(first) - 1
        out.append(inverse)
    if return_counts:
        out.append(np.diff(np.append(np.flatnonzero(first), n)).astype(np.intp, copy=False))
    return out[0] if len(out) == 1 else tuple(out)


def _digits(a: np.ndarray) -> tuple[list[np.ndarray], list[tuple[int, Any]]]:
    """Each column as digits 0..radix-1 in the column's order, and how to read them back.

    A column spanning fewer values than there are rows enters by its offset from its minimum
    (read back by adding it), one spanning more (grid cells of positions) by its rank among
    its distinct values (read back by indexing them).
    """
    digits, decode = [], []
    for column in a.T:
        lo, hi = int(column.min()), int(column.max())
        if hi - lo < a.shape[0]:
            digits.append(column - lo)
            decode.append((hi - lo + 1, lo))
        else:
            values, rank = np.unique(column, return_inverse=True)
            digits.append(rank.reshape(-1).astype(np.int64, copy=False))
            decode.append((values.shape[0], values))
    return digits, decode


def _decoded(keys: np.ndarray, decode: list[tuple[int, Any]]) -> np.ndarray:
    """Read mixed-radix ``keys`` back into rows (the inverse of making them)."""
    rows = np.empty((keys.shape[0], len(decode)), dtype=np.int64)
    rest = keys
    for j in range(len(decode) - 1, -1, -1):
        radix, back = decode[j]
        rest, digit = np.divmod(rest, radix)
        rows[:, j] = digit + back if isinstance(back, int) else back[digit]
    return rows
