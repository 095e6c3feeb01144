"""Input checks shared by every entry point.

Every check copies what it returns (never a view of the caller's array) and raises
``TypeError``/``ValueError`` whose message names the argument and the offending value.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from .wording import OptionError

__all__ = ["as_faces", "as_signal", "as_vertices", "check_int", "check_tol"]


def _array(x: Any, name: str, what: str) -> np.ndarray:
    """Return a copy of ``x``; if numpy cannot take it, a TypeError: ``name`` must be ``what``."""
    try:
        return np.array(x, copy=True)
    except Exception as exc:
        shape = getattr(x, "shape", None)
        got = f"type {type(x).__name__}"
        if shape is not None:
            got = f"shape {tuple(shape)} and dtype {getattr(x, 'dtype', '?')}"
        raise TypeError(f"{name} must be {what}; got {got}") from exc


def as_vertices(vertices: Any, *, name: str = "vertices") -> np.ndarray:
    """Return a float64 ``(n, 3)`` copy of ``vertices`` after checking it.

    Raises
    ------
    TypeError
        If ``vertices`` is not numeric.
    ValueError
        If it is not ``(n, 3)`` with ``n >= 1`` or holds NaN/inf.
    """
    arr = _array(vertices, name, "an (n, 3) array of floats")
    if arr.dtype == bool or not (
        np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
    ):
        raise TypeError(f"{name} must be an (n, 3) array of floats; got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3); got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name} is empty: the geometry has no vertices")
    arr = arr.astype(np.float64, copy=False)
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(arr), axis=1)))
        raise ValueError(f"{name} holds NaN or inf coordinates in {bad} of {arr.shape[0]} rows")
    return arr


def as_faces(faces: Any, n_vertices: int, *, name: str = "faces") -> np.ndarray:
    """Return an int64 ``(m, 3)`` copy of ``faces`` with every index in ``[0, n_vertices)``.

    Raises
    ------
    TypeError
        If ``faces`` does not hold integers.
    ValueError
        If it is not ``(m, 3)`` with ``m >= 1`` or an index is out of range.
    """
    arr = _array(faces, name, "an (m, 3) array of ints")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (m, 3); got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name} is empty: the mesh has no triangles")
    if np.issubdtype(arr.dtype, np.floating):
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise TypeError(
                f"{name} must hold integer vertex indices; got non-integral {arr.dtype}"
            )
    elif arr.dtype == bool or not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"{name} must hold integer vertex indices; got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    lo, hi = int(arr.min()), int(arr.max())
    if lo < 0 or hi >= n_vertices:
        raise ValueError(
            f"{name} index out of range: indices span [{lo}, {hi}] but there are "
            f"{n_vertices} vertices (valid: 0..{n_vertices - 1})"
        )
    return arr


def as_signal(f: Any, n: int, *, name: str = "f") -> np.ndarray:
    """Return a float64 copy of a per-vertex signal of shape ``(n,)`` or ``(n, d)``.

    Raises
    ------
    TypeError
        If ``f`` is not numeric.
    ValueError
        If its first dimension is not ``n``, it has more than 2 dimensions or holds NaN/inf.
    """
    arr = _array(f, name, "a numeric array")
    if arr.dtype == bool:
        arr = arr.astype(np.float64)
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise TypeError(f"{name} must be a numeric array; got dtype {arr.dtype}")
    if arr.ndim not in (1, 2):
        raise ValueError(f"{name} must have shape (n,) or (n, d); got {arr.shape}")
    if arr.shape[0] != n:
        raise ValueError(f"{name} has {arr.shape[0]} values but the shape has {n} vertices")
    arr = arr.astype(np.float64, copy=False)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} holds NaN or inf values")
    return arr


def check_int(value: Any, *, name: str, minimum: int, maximum: int | None = None) -> int:
    """Return ``value`` as an ``int`` after checking ``minimum <= value <= maximum``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise OptionError(name, f"must be an integer; got {value!r} of type {type(value).__name__}")
    value = int(value)
    if value < minimum or (maximum is not None and value > maximum):
        hi = "" if maximum is None else f" and <= {maximum}"
        raise OptionError(name, f"must be >= {minimum}{hi}; got {value}")
    return value


def check_tol(tol: Any, *, name: str = "tol") -> float:
    """Return ``tol`` as a float strictly inside ``(0, 1)``."""
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real):
        raise OptionError(name, f"must be a float in (0, 1); got {tol!r}")
    tol = float(tol)
    if not (0.0 < tol < 1.0):
        raise OptionError(name, f"must lie strictly between 0 and 1; got {tol}")
    return tol
