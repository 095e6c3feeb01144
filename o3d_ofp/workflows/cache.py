"""Caches of eigenbases and OFP bases: decompose a shape once, reuse the ``.npz`` every later time.

A cached file is keyed on a digest of the input's vertices and faces and of every option that
changes the result (cleaning, Laplacian, k, order, threshold), so a changed mesh or option
never picks up a stale basis. An entry that cannot be read (zero bytes, cut short, damaged,
written by something else) or that belongs to another shape is a miss: it is recomputed and
rewritten, with a warning. Entries are written atomically, so concurrent writers (threads or
processes of a collection run) never leave a half-written file.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import zipfile
import zlib
from typing import Any

import numpy as np

from ..core._atomic import atomic_path
from ..core.basis import OFPBasis, ofp_basis
from ..core.orthogonalize import resolve_tol
from ..core.spectrum import DEFAULT_K, DIGEST_OPTIONS, EigenBasis, eigenbasis, shape_digest

__all__ = [
    "basis_cache_path",
    "cached_basis",
    "default_cache_dir",
    "fetch_basis",
    "fetch_eigenbasis",
    "load_eigenbasis",
    "save_eigenbasis",
]

logger = logging.getLogger(__name__)

_EIG_FORMAT_VERSION = 1
_EIG_KIND = "o3d_ofp.EigenBasis"
#: What reading a damaged ``.npz`` raises (zero bytes: EOFError; cut short:
#: zipfile.BadZipFile; a damaged member: zlib.error; a missing array: KeyError).
_DAMAGED = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)


def default_cache_dir() -> str:
    """``$XDG_CACHE_HOME/o3d_ofp`` (default ``~/.cache/o3d_ofp``)."""
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(root, "o3d_ofp")


def _entry(
    vertices: Any, faces: Any, key: str, cache_dir: Any, options: dict[str, Any], prefix: str = ""
) -> tuple[str, str]:
    """``(path, digest)`` of a cache entry: the shape digest, ``key`` and the other options."""
    folder = os.fspath(cache_dir) if cache_dir is not None else default_cache_dir()
    own = {o: v for o, v in options.items() if o in DIGEST_OPTIONS}  # those the digest covers
    digest = shape_digest(vertices, faces, **own)
    rest = sorted((o, v) for o, v in options.items() if o not in DIGEST_OPTIONS)
    name = hashlib.blake2b(f"{prefix}{digest}|{key}|{rest!r}".encode(), digest_size=16)
    return os.path.join(folder, f"{'eig-' if prefix else ''}{name.hexdigest()}.npz"), digest


def _cached(path: str, digest: str, load: Any, compute: Any, save: Any, what: str) -> Any:
    """Return ``(value, True)`` read from ``path``, else ``(value, False)`` computed and written.

    An entry that cannot be read, or that is not of ``digest`` (another shape), is a miss
    (logged).
    """
    if os.path.exists(path):
        try:
            value = load(path)
        except _DAMAGED as exc:
            logger.warning("damaged cache entry %s, recomputing and rewriting it: %s", path, exc)
        else:
            if (value if isinstance(value, EigenBasis) else value.eig).digest == digest:
                logger.info("%s loaded from cache %s", what, path)
                return value, True
            logger.warning("cache file %s belongs to another shape; recomputing", path)
    value = compute()
    os.makedirs(os.path.dirname(path), exist_ok=True)
    save(value, path)
    logger.info("%s cached in %s", what, path)
    return value, False


def save_eigenbasis(eig: EigenBasis, path: str | os.PathLike[str]) -> None:
    """Write an eigenbasis to a ``.npz`` file, atomically.

    Parameters
    ----------
    eig : EigenBasis
        The eigenbasis (evals (k+1,), evecs (n, k+1), mass (n,), stiffness (n, n), ...).
    path : str or os.PathLike
        Destination (``.npz`` appended when missing).
    """
    payload = {
        "format_version": np.int64(_EIG_FORMAT_VERSION),
        "kind": np.array(_EIG_KIND),
        **eig.to_arrays(),
    }
    path = os.fspath(path)
    if not path.endswith(".npz"):
        path += ".npz"
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **payload)


def load_eigenbasis(path: str | os.PathLike[str]) -> EigenBasis:
    """Read an eigenbasis written by :func:`save_eigenbasis`.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.npz`` file.

    Returns
    -------
    EigenBasis

    Raises
    ------
    ValueError
        If the file is empty, cut short, damaged or not an o3d_ofp eigenbasis (the message
        names it).
    """
    name = os.fspath(path)
    try:
        # Our own handle: np.load leaks the one it opens when the zip directory is damaged.
        with open(name, "rb") as fh, np.load(fh, allow_pickle=False) as data:
            if "kind" not in data or str(data["kind"]) != _EIG_KIND:
                raise ValueError("not an o3d_ofp eigenbasis file")
            if int(data["format_version"]) != _EIG_FORMAT_VERSION:
                raise ValueError("unknown eigenbasis format version")
            return EigenBasis.from_arrays(data)
    except _DAMAGED as exc:
        raise ValueError(f"{name}: cannot read a cached eigenbasis ({exc})") from exc


def fetch_eigenbasis(
    vertices: Any, faces: Any = None, *, k: int, clamp_k: bool = False,
    cache_dir: str | os.PathLike[str] | None = None, **eig_options: Any,
) -> tuple[EigenBasis, bool]:  # fmt: skip
    """Return a shape's eigenbasis from the cache, or compute and cache it.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex positions.
    faces : (m, 3) array_like of int, optional
        Triangles (``None``: a point cloud).
    k : int
        Non-constant eigenfunctions.
    clamp_k : bool, default False
        As in :func:`o3d_ofp.eigenbasis`.
    cache_dir : str or os.PathLike, optional
        Cache folder (default :func:`default_cache_dir`); created if missing.
    **eig_options
        Other keyword options of :func:`o3d_ofp.eigenbasis` (``components``, ...).

    Returns
    -------
    eig : EigenBasis
        ``k + 1`` eigenpairs (fewer with ``clamp_k`` on a small shape).
    cached : bool
        Whether it came from the cache.
    """
    key = f"k={int(k)}|clamp={bool(clamp_k)}"
    path, digest = _entry(vertices, faces, key, cache_dir, eig_options, "eig|")
    compute = functools.partial(eigenbasis, vertices, faces, k=k, clamp_k=clamp_k, **eig_options)
    return _cached(path, digest, load_eigenbasis, compute, save_eigenbasis, "eigenbasis")


def basis_cache_path(
    vertices: Any, faces: Any = None, *, k: int = DEFAULT_K, order: int = 2,
    tol: float | None = None, preset: str | None = None,
    cache_dir: str | os.PathLike[str] | None = None, **eig_options: Any,
) -> str:  # fmt: skip
    """Path under which :func:`cached_basis` keeps this basis (it may not exist).

    Parameters
    ----------
    vertices, faces, k, order, tol, preset, cache_dir, **eig_options
        As in :func:`cached_basis`.

    Returns
    -------
    str
        ``<cache_dir>/<key>.npz``, the key a digest of the shape and of every option.
    """
    key = f"k={k}|order={order}|tol={resolve_tol(tol, preset)!r}"
    return _entry(vertices, faces, key, cache_dir, eig_options)[0]


def fetch_basis(
    vertices: Any, faces: Any = None, *, k: int = DEFAULT_K, order: int = 2,
    tol: float | None = None, preset: str | None = None,
    cache_dir: str | os.PathLike[str] | None = None, eig: EigenBasis | None = None,
    **eig_options: Any,
) -> tuple[OFPBasis, bool]:  # fmt: skip
    """Return a shape's OFP basis from the cache, or compute (maybe from ``eig``) and cache it.

    Parameters
    ----------
    vertices, faces, k, order, tol, preset, cache_dir, **eig_options
        As in :func:`cached_basis`.
    eig : EigenBasis, optional
        This shape's eigenbasis with at least ``k`` eigenfunctions (e.g. the ``k = 99`` one
        of the map estimation): on a miss the basis is built from its first ``k`` instead of
        a new eigensolve. Its digest must be the shape's.

    Returns
    -------
    basis : OFPBasis
        The basis (Q (n, q)); its file is :func:`basis_cache_path`.
    cached : bool
        Whether it came from the cache.

    Raises
    ------
    ValueError
        If ``eig`` belongs to another shape or has fewer than ``k`` eigenfunctions.
    """
    t = resolve_tol(tol, preset)
    key = f"k={k}|order={order}|tol={t!r}"
    path, digest = _entry(vertices, faces, key, cache_dir, eig_options)
    if eig is not None and (eig.digest != digest or eig.k < k):
        raise ValueError(
            f"eig must be this shape's eigenbasis with at least k={k} eigenfunctions (it has "
            f"{eig.k}{'' if eig.digest == digest else ' and belongs to another shape'})"
        )

    def compute() -> OFPBasis:
        given = eig if eig is not None else eigenbasis(vertices, faces, k=k, **eig_options)
        return ofp_basis(given, order=order, tol=t, k=k)

    return _cached(path, digest, OFPBasis.load, compute, OFPBasis.save, "basis")


def cached_basis(
    vertices: Any, faces: Any = None, *, k: int = DEFAULT_K, order: int = 2,
    tol: float | None = None, preset: str | None = None,
    cache_dir: str | os.PathLike[str] | None = None, **eig_options: Any,
) -> OFPBasis:  # fmt: skip
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
        The basis; its file is :func:`basis_cache_path`. A damaged entry is recomputed and
        rewritten.
    """
    return fetch_basis(
        vertices, faces, k=k, order=order, tol=tol, preset=preset, cache_dir=cache_dir,
        **eig_options,
    )[0]  # fmt: skip
