"""Reading correspondence files (mesh files are read by :mod:`o3d_ofp.boundary.io`)."""

from __future__ import annotations

import os

import numpy as np

__all__ = ["read_vts"]


def read_vts(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a ``.vts`` correspondence file: one 1-based vertex index per line.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    (m,) ndarray of int64
        The indices, converted to 0-based.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If a line is not a positive integer.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    try:
        values = np.loadtxt(path, dtype=np.float64, ndmin=1)
    except UnicodeDecodeError:
        raise ValueError(
            f"{path}: not a .vts file (one vertex index per line): it is a binary file"
        ) from None
    except ValueError as exc:
        raise ValueError(f"{path}: not a .vts file (one vertex index per line): {exc}") from exc
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f"{path}: expected one vertex index per line; got shape {values.shape}")
    if np.any(values != np.round(values)) or values.min() < 1:
        raise ValueError(f"{path}: vertex indices must be positive integers (1-based)")
    return values.astype(np.int64) - 1
