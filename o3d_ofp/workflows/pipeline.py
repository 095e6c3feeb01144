"""End-to-end transfer between two shapes, on arrays: map, bases, transfer matrix, signal.

The Open3D-level functions (:func:`o3d_ofp.adapters.transfer_colors`,
:func:`o3d_ofp.adapters.transfer_detail`) call these.

Defaults follow the paper: order 2 with k₁ = 29, k₂ = 39 non-constant eigenfunctions (its
K = 30 / 40, for humans); order 3 with k ≈ 11-14 suits other shapes (Tables 2, 5, 6).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..core._validation import as_signal, check_int
from ..core.basis import OFPBasis, ofp_basis
from ..core.correspondence import check_fmap, check_p2p, p2p_from_fmap
from ..core.geometry import vertex_normals
from ..core.spectrum import EigenBasis, eigenbasis
from ..core.transfer import transfer_matrix, transfer_signal
from .matching import ESTIMATION_K, Correspondence, match_eigenbases

__all__ = [
    "detail_heights",
    "eigenbases_for_transfer",
    "pull_back",
    "transfer_detail_arrays",
    "transfer_function",
]

logger = logging.getLogger(__name__)


def _bases(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    k1: int,
    k2: int,
    order: int,
    tol: float | None,
    preset: str | None,
) -> tuple[OFPBasis, OFPBasis]:
    k1 = check_int(k1, name="k1", minimum=1, maximum=eig_1.k)
    k2 = check_int(k2, name="k2", minimum=1, maximum=eig_2.k)
    return (
        ofp_basis(eig_1, order=order, tol=tol, preset=preset, k=k1),
        ofp_basis(eig_2, order=order, tol=tol, preset=preset, k=k2),
    )


def transfer_function(
    f_1: Any,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k1: int = 29,
    k2: int = 39,
    order: int = 2,
    tol: float | None = None,
    preset: str | None = None,
    correspondence: Correspondence | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    method: str = "p2p",
    bases: tuple[OFPBasis, OFPBasis] | None = None,
) -> np.ndarray:
    """Transfer a per-vertex signal from a source to a target shape with OFP bases.

    Parameters
    ----------
    f_1 : (n1,) or (n1, d) array_like of float
        Source signal.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases (with at least ``k1`` / ``k2`` eigenfunctions; more are
        used by ZoomOut when the map is estimated).
    k1, k2 : int, default 29, 39
        Eigenfunctions multiplied on each side.
    order : int, default 2
        Product order.
    tol, preset
        Orthogonalization threshold (default "ours", 1e-2); see :func:`o3d_ofp.ofp_basis`.
    correspondence : Correspondence, optional
        A map from :func:`o3d_ofp.match` (or :meth:`Correspondence.load`); its point map is
        used.
    fmap_12 : array_like, optional
        A functional map (at least (k2+1, k1+1)); its nearest-neighbour p2p map is used.
    p2p_21 : (n2,) array_like of int, optional
        A point-to-point map (target vertex → source vertex), used directly.
    landmarks : (p, 2) array_like of int, optional
        Known pairs, when the map is estimated.
    method : {"p2p", "analytic"}, default "p2p"
        How the transfer matrix is computed (see :func:`o3d_ofp.transfer_matrix`).
    bases : (OFPBasis, OFPBasis), optional
        Precomputed bases (then ``k1``, ``k2``, ``order``, ``tol`` and ``preset`` are unused).

    Returns
    -------
    (n2,) or (n2, d) ndarray
        The transferred signal.
    """
    if method not in ("p2p", "analytic"):
        raise ValueError(f"method must be 'p2p' or 'analytic'; got {method!r}")
    f = as_signal(f_1, eig_1.n_vertices, name="f_1")
    B_1, B_2 = bases if bases is not None else _bases(eig_1, eig_2, k1, k2, order, tol, preset)
    if sum(x is not None for x in (correspondence, p2p_21, fmap_12)) > 1:
        raise ValueError("give at most one of correspondence, p2p_21 and fmap_12")
    if correspondence is not None:
        correspondence.check(eig_1.n_vertices, eig_2.n_vertices)
        p2p = correspondence.p2p_21
    elif p2p_21 is not None:
        p2p = check_p2p(p2p_21, eig_2.n_vertices, eig_1.n_vertices)
    elif fmap_12 is not None:
        C = np.asarray(fmap_12, dtype=np.float64)
        check_fmap(C, B_2.k + 1, B_1.k + 1)
        p2p = p2p_from_fmap(C, eig_1, eig_2)
    else:
        p2p = match_eigenbases(eig_1, eig_2, landmarks=landmarks).p2p_21
    if method == "analytic":
        if fmap_12 is None:
            raise ValueError("method='analytic' needs fmap_12")
        transfer_12 = transfer_matrix(B_1, B_2, fmap_12, method="analytic")
    else:
        transfer_12 = transfer_matrix(B_1, B_2, method="p2p", p2p_21=p2p)
    return transfer_signal(f, B_1, B_2, transfer_12)


def detail_heights(eig: EigenBasis, normals: np.ndarray, *, k_low: int | None = None) -> np.ndarray:
    """Fine detail as a height along the normals: ``<X − low-pass(X), n>``.

    Parameters
    ----------
    eig : EigenBasis
        The shape's eigenbasis (its vertices are the coordinates X).
    normals : (n, 3) ndarray
        Unit vertex normals.
    k_low : int, optional
        Eigenfunctions of the low-pass reconstruction (default: all of ``eig``).

    Returns
    -------
    (n,) ndarray
        Signed height of every vertex above the smooth shape.
    """
    low = eig if k_low is None else eig.truncate(k_low)
    X = eig.vertices
    smooth = low.reconstruct(low.project(X))
    return np.einsum("ij,ij->i", X - smooth, normals)


def transfer_detail_arrays(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    mode: str = "add",
    k1: int = 29,
    k2: int = 39,
    order: int = 2,
    tol: float | None = None,
    preset: str | None = "ours*",
    correspondence: Correspondence | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    k_low: int | None = None,
    normals_1: Any = None,
    normals_2: Any = None,
    bases: tuple[OFPBasis, OFPBasis] | None = None,
) -> np.ndarray:
    """Move the target's vertices to carry the source's geometric detail.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source (with detail) and target eigenbases.
    mode : {"add", "replace"}, default "add"
        "replace" (the paper's Fig. 13): the source's vertex coordinates are transferred and
        replace the target's. "add": the target keeps its own shape and pose and receives the
        source's fine detail as heights along its normals: the source's coordinates minus
        their low-pass reconstruction (``k_low`` eigenfunctions), measured along the source
        normals, transferred, scaled by √(area₂/area₁) and added along the target normals.
    k1, k2, order, tol, preset, correspondence, fmap_12, p2p_21, landmarks
        As in :func:`transfer_function` (default preset "ours*", which the paper prefers for
        detail).
    k_low : int, optional
        Low-pass size for "add" (default: ``k1``).
    normals_1, normals_2 : (n, 3) array_like, optional
        Unit normals (default: area-weighted vertex normals; required for point clouds).
    bases : (OFPBasis, OFPBasis), optional
        Precomputed bases, as in :func:`transfer_function`.

    Returns
    -------
    (n2, 3) ndarray
        New target vertex positions.
    """
    if mode not in ("add", "replace"):
        raise ValueError(f"mode must be 'add' or 'replace'; got {mode!r}")
    kw = dict(
        k1=k1,
        k2=k2,
        order=order,
        tol=tol,
        preset=preset,
        correspondence=correspondence,
        fmap_12=fmap_12,
        p2p_21=p2p_21,
        landmarks=landmarks,
        bases=bases,
    )
    if mode == "replace":
        return transfer_function(eig_1.vertices, eig_1, eig_2, **kw)
    n1 = _normals(eig_1, normals_1, "normals_1")
    n2 = _normals(eig_2, normals_2, "normals_2")
    heights = detail_heights(eig_1, n1, k_low=k1 if k_low is None else k_low)
    moved = transfer_function(heights, eig_1, eig_2, **kw)
    moved *= np.sqrt(eig_2.area / eig_1.area)
    return eig_2.vertices + moved[:, None] * n2


def _normals(eig: EigenBasis, normals: Any, name: str) -> np.ndarray:
    if normals is not None:
        arr = as_signal(normals, eig.n_vertices, name=name)
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise ValueError(f"{name} must have shape (n, 3); got {arr.shape}")
        norm = np.linalg.norm(arr, axis=1, keepdims=True)
        return np.divide(arr, norm, out=np.zeros_like(arr), where=norm > 0)
    if eig.faces is None:
        raise ValueError(
            f"{name} are needed for a point cloud (it has no faces to compute them from)"
        )
    normals = vertex_normals(eig.vertices, eig.faces)
    if eig.cleaning is not None:
        # Faces reference only the representative of each welded group: give every input
        # vertex (duplicate or removed) the normal of the cleaned vertex standing for it.
        c = eig.cleaning
        normals = normals[c.representative[c.index]]
    return normals


def eigenbases_for_transfer(
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
    k1: int,
    k2: int,
    fmap_12: Any,
    p2p_21: Any,
    eigenbases: tuple[Any, Any] | None,
    bases: tuple[Any, Any] | None,
    correspondence: Correspondence | None = None,
) -> tuple[Any, Any]:
    """Eigenbases for a transfer: given ones (checked), else those of the bases, else computed.

    The one place that decides how many eigenfunctions a map needs.

    Computed ones are as large as the map needs: a given map may be larger than k1/k2 (all of
    it is used); an estimated map is refined by ZoomOut to ~100 eigenfunctions (as in pyFM's
    standard pipeline), never more than a shape allows.
    """
    estimate = fmap_12 is None and p2p_21 is None and correspondence is None
    if eigenbases is None and bases is not None and not estimate:
        eigenbases = (bases[0].eig, bases[1].eig)  # no estimation: the bases' own suffice
    if eigenbases is None:
        if estimate:
            k1, k2 = max(k1, ESTIMATION_K), max(k2, ESTIMATION_K)
        elif fmap_12 is not None:
            rows, cols = np.shape(fmap_12)
            k1, k2 = max(k1, cols - 1), max(k2, rows - 1)
        return (
            eigenbasis(V1, F1, k=k1, clamp_k=estimate),
            eigenbasis(V2, F2, k=k2, clamp_k=estimate),
        )
    for eig, V, name in ((eigenbases[0], V1, "source"), (eigenbases[1], V2, "target")):
        if eig.n_vertices != V.shape[0]:
            raise ValueError(
                f"the {name} eigenbasis has {eig.n_vertices} vertices but the {name} has "
                f"{V.shape[0]}: it belongs to another shape"
            )
    return eigenbases


def pull_back(f_1: Any, correspondence: Correspondence, faces_1: Any = None) -> np.ndarray:
    """Carry a source signal to the target exactly through the map (no basis).

    With a surface map (``correspondence.barycentric_21``, e.g. ``match(method="closest")``)
    every target vertex gets the source signal interpolated at its point on the source
    surface; otherwise the value at its source vertex.

    Parameters
    ----------
    f_1 : (n1,) or (n1, d) array_like of float
        Source signal.
    correspondence : Correspondence
        The map.
    faces_1 : (m1, 3) array_like of int, optional
        The source triangles the surface map refers to (required with a surface map).

    Returns
    -------
    (n2,) or (n2, d) ndarray
    """
    f = as_signal(f_1, correspondence.n_source, name="f_1")
    if correspondence.barycentric_21 is None:
        return f[correspondence.p2p_21]
    if faces_1 is None:
        raise ValueError("a surface map needs the source triangles (faces_1)")
    F = np.asarray(faces_1)
    if F.ndim != 2 or F.shape[1] != 3 or correspondence.faces_21.max() >= F.shape[0]:
        raise ValueError(
            f"faces_1 has shape {F.shape}: not the triangles the correspondence refers to"
        )
    corners = F[correspondence.faces_21]  # (n2, 3) source vertices
    w = correspondence.barycentric_21
    if f.ndim == 1:
        return np.einsum("ij,ij->i", f[corners], w)
    return np.einsum("ijd,ij->id", f[corners], w)
