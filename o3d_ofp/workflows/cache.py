"""Basis cache: decompose a shape once, reuse the ``.npz`` every later time.

A cached file is keyed on a digest of the input's vertices and faces and of every option that
changes the result (cleaning, Laplacian, k, order, threshold), so a changed mesh or option
never picks up a stale basis.
"""

from __future__ import annotations

import hashlib
import logging
import os
from typing import Any

from ..core.basis import OFPBasis, ofp_basis
from ..core.orthogonalize import resolve_tol
from ..core.spectrum import DIGEST_OPTIONS, eigenbasis, shape_digest

__all__ = ["cached_basis", "default_cache_dir"]

logger = logging.getLogger(__name__)


def default_cache_dir() -> str:
    """``$XDG_CACHE_HOME/o3d_ofp`` (default ``~/.cache/o3d_ofp``)."""
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(root, "o3d_ofp")


def cached_basis(
    vertices: Any,
    faces: Any = None,
    *,
    k: int = 29,
    order: int = 2,
    tol: float | None = None,
    preset: str | None = None,
    cache_dir: str | os.PathLike[str] | None = None,
    **eig_options: Any,
) -> Any:
    """Return the OFP basis of a shape, from the cache when it was computed before.

    Parameters
    ----------
    vertices, faces
        As in :func:`o3d_ofp.eigenbasis`.
    k, order, tol, preset
        As in :func:`o3d_ofp.eigenbasis` / :func:`o3d_ofp.ofp_basis`.
    cache_dir : str or os.PathLike, optional
        Folder of cached bases (default :func:`default_cache_dir`); created if missing.
    **eig_options
        Other keyword options of :func:`o3d_ofp.eigenbasis` (``components``, ...).

    Returns
    -------
    OFPBasis
        The basis; its file is ``<cache_dir>/<digest>.npz``.
    """
    folder = os.fspath(cache_dir) if cache_dir is not None else default_cache_dir()
    os.makedirs(folder, exist_ok=True)
    digest = shape_digest(
        vertices, faces, **{o: v for o, v in eig_options.items() if o in DIGEST_OPTIONS}
    )
    t = resolve_tol(tol, preset)
    rest = sorted((o, v) for o, v in eig_options.items() if o not in DIGEST_OPTIONS)
    key = hashlib.blake2b(
        f"{digest}|k={k}|order={order}|tol={t!r}|{rest!r}".encode(), digest_size=16
    )
    path = os.path.join(folder, key.hexdigest() + ".npz")
    if os.path.isfile(path):
        try:
            B = OFPBasis.load(path)
        except ValueError as exc:
            logger.warning("ignoring unreadable cache file %s: %s", path, exc)
        else:
            if B.eig.digest == digest:
                logger.info("basis loaded from cache %s", path)
                return B
            logger.warning("cache file %s belongs to another shape; recomputing", path)
    B = ofp_basis(eigenbasis(vertices, faces, k=k, **eig_options), order=order, tol=t)
    B.save(path)
    logger.info("basis cached in %s", path)
    return B
