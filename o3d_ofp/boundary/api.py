"""The geometry-level API: Open3D geometries (or array tuples) in, new geometries out.

Built on :mod:`o3d_ofp.workflows`; every function converts its inputs with
:mod:`o3d_ofp.boundary.convert`, never modifies them, and returns a new geometry of the
target's own kind.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from ..core import spectrum
from ..core._validation import as_signal, check_int
from ..core._warnings import warn
from ..core.basis import OFPBasis, check_basis_options, ofp_basis
from ..core.correspondence import p2p_from_fmap
from ..core.filtering import (
    DEFAULT_SMOOTH,
    MAX_SHARPEN,
    MAX_SMOOTH,
    check_amount,
    sharpen_coordinates,
    smooth_coordinates,
    spectral_filter,
)
from ..core.spectrum import EigenBasis
from ..workflows import cache
from ..workflows.detail import (
    DETAIL_BAND,
    ROTATION_K,
    check_coordinates_area,
    check_detail_options,
    transfer_detail_frames,
)
from ..workflows.matching import (
    ESTIMATION_K,
    FIT_K,
    Correspondence,
    check_correspondence,
)
from ..workflows.pipeline import (
    check_method,
    check_partial_transfer,
    estimate_map,
    estimate_map_arrays,
    prepare_transfer,
    pull_back,
    transfer_on_shapes,
    warn_other_shape,
)
from .closest import closest_correspondence
from .convert import (
    geometry_kind,
    geometry_to_arrays,
    is_open3d_geometry,
    like_target,
    point_normals,
    stray_colors,
    vertex_colors,
)
from .io import read_if_path
from .texture import has_texture_image, has_uvs, mesh_texture

__all__ = [
    "as_arrays",
    "cached_basis",
    "eigenbasis",
    "filter_geometry",
    "match",
    "shape_digest",
    "transfer_colors",
    "transfer_detail",
]

logger = logging.getLogger(__name__)


def as_arrays(shape: Any, faces: Any = None, *, name: str = "shape") -> tuple[Any, Any]:
    """(vertices, faces) of an Open3D geometry, a ``(vertices, faces)`` tuple, or arrays.

    Parameters
    ----------
    shape : Open3D TriangleMesh / PointCloud (legacy or tensor), (vertices, faces) tuple,
        (n, 3) array_like of vertex positions, or a file path (read with
        :func:`o3d_ofp.read_geometry`)
        The shape.
    faces : (m, 3) array_like of int, optional
        Triangles when ``shape`` is an array of vertices (``None``: a point cloud).
    name : str
        Name used in error messages.

    Returns
    -------
    vertices : (n, 3) ndarray of float64 (a copy)
    faces : (m, 3) ndarray of int64 or None
    """
    shape = read_if_path(shape, name)
    if is_open3d_geometry(shape):
        if faces is not None:
            raise ValueError(f"faces must be None when {name} is an Open3D geometry")
        return geometry_to_arrays(shape)
    if isinstance(shape, tuple):
        if len(shape) != 2:
            raise ValueError(f"{name} as a tuple must be (vertices, faces); got {len(shape)} items")
        if faces is not None:
            raise ValueError(f"faces must be None when {name} is a (vertices, faces) tuple")
        shape, faces = shape
    if shape is None or (np.ndim(shape) == 0 and not isinstance(shape, np.ndarray)):
        # a number or another object, not a shape (said by name, not as "shape ()")
        raise TypeError(
            f"{name} must be an Open3D TriangleMesh or PointCloud, a file path, a (vertices, "
            f"faces) tuple or an (n, 3) array of vertices; got {type(shape).__name__}"
        )
    return spectrum.input_arrays(shape, faces)


def eigenbasis(
    mesh_or_vertices: Any,
    faces: Any = None,
    *,
    k: int = 29,
    weld_tolerance: float | None = 1e-9,
    components: str = "auto",
    mollify_factor: float = 1e-5,
    n_neighbors: int = 30,
    maxiter: int | None = None,
    clamp_k: bool = False,
    factorization: str = "auto",
) -> EigenBasis:
    """Compute the ``k + 1`` smallest Laplace-Beltrami eigenpairs of a mesh or point cloud.

    Parameters
    ----------
    mesh_or_vertices : Open3D TriangleMesh / PointCloud (legacy or tensor), (vertices, faces)
        tuple, or (n, 3) array_like of float
        The shape; with an array of vertices, ``faces`` gives the triangles (``None``: a
        point cloud).
    faces : (m, 3) array_like of int, optional
        Triangles when ``mesh_or_vertices`` is an array.
    k : int, default 29
        Non-constant eigenfunctions (the paper's K = 30 is ``k=29``).
    weld_tolerance, components, mollify_factor, n_neighbors, maxiter, clamp_k, factorization
        As in :func:`o3d_ofp.core.spectrum.eigenbasis`.

    Returns
    -------
    EigenBasis
        Eigenvalues ``(k+1,)``, M-orthonormal eigenvectors ``(n, k+1)`` with the constant first,
        the lumped mass and the stiffness, on the input's n vertices.

    References
    ----------
    .. [1] G. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021. doi:10.1111/cgf.142645
    """
    V, F = as_arrays(mesh_or_vertices, faces, name="mesh_or_vertices")
    return spectrum.eigenbasis(
        V,
        F,
        k=k,
        weld_tolerance=weld_tolerance,
        components=components,
        mollify_factor=mollify_factor,
        n_neighbors=n_neighbors,
        maxiter=maxiter,
        clamp_k=clamp_k,
        factorization=factorization,
    )


def shape_digest(
    mesh_or_vertices: Any,
    faces: Any = None,
    *,
    weld_tolerance: float | None = 1e-9,
    components: str = "auto",
    mollify_factor: float = 1e-5,
    n_neighbors: int = 30,
) -> str:
    """Identify a shape and the options its eigenbasis depends on (``EigenBasis.digest``).

    Parameters
    ----------
    mesh_or_vertices, faces
        As in :func:`eigenbasis`.
    weld_tolerance, components, mollify_factor, n_neighbors
        As in :func:`eigenbasis`.

    Returns
    -------
    str
        A 32-character hex digest: equal inputs and options give equal digests.
    """
    V, F = as_arrays(mesh_or_vertices, faces, name="mesh_or_vertices")
    return spectrum.shape_digest(
        V,
        F,
        weld_tolerance=weld_tolerance,
        components=components,
        mollify_factor=mollify_factor,
        n_neighbors=n_neighbors,
    )


def cached_basis(
    mesh_or_vertices: Any,
    faces: Any = None,
    *,
    k: int = 29,
    order: int = 2,
    tol: float | None = None,
    preset: str | None = None,
    cache_dir: Any = None,
    weld_tolerance: float | None = 1e-9,
    components: str = "auto",
    mollify_factor: float = 1e-5,
    n_neighbors: int = 30,
) -> OFPBasis:
    """Return the OFP basis of a shape, from the cache when it was computed before.

    Parameters
    ----------
    mesh_or_vertices, faces
        As in :func:`eigenbasis`.
    k, order, tol, preset
        As in :func:`eigenbasis` / :func:`o3d_ofp.ofp_basis`.
    cache_dir : str or os.PathLike, optional
        Folder of cached bases (default ``$XDG_CACHE_HOME/o3d_ofp``); created if missing.
    weld_tolerance, components, mollify_factor, n_neighbors
        As in :func:`eigenbasis`.

    Returns
    -------
    OFPBasis
        The basis; its file is ``<cache_dir>/<digest>.npz``.
    """
    V, F = as_arrays(mesh_or_vertices, faces, name="mesh_or_vertices")
    return cache.cached_basis(
        V,
        F,
        k=k,
        order=order,
        tol=tol,
        preset=preset,
        cache_dir=cache_dir,
        weld_tolerance=weld_tolerance,
        components=components,
        mollify_factor=mollify_factor,
        n_neighbors=n_neighbors,
    )


def match(
    source: Any,
    target: Any,
    *,
    method: str = "estimate",
    align: bool = False,
    partial: bool = False,
    landmarks: Any = None,
    k_fit: int = FIT_K,
    zoomout_to: int = ESTIMATION_K,
    zoomout_subsample: int | None = 2000,
    descriptors: str = "wks",
    w_orient: float = 1.0,
    components: str = "auto",
    eigenbases: tuple[EigenBasis, EigenBasis] | None = None,
) -> Correspondence:
    """Find, for every target vertex, its source vertex: one call, any units, with a verdict.

    Descriptor fit (WKS, Laplacian and descriptor commutativity, orientation-preserving term)
    then ZoomOut to 100 eigenfunctions and the point map, all on unit-area copies of the
    shapes: the map does not change when either shape is scaled, moved or rotated.

    Parameters
    ----------
    source, target : Open3D TriangleMesh or PointCloud (legacy or tensor), or a
        (vertices, faces) tuple of arrays (faces None for points)
        The shapes; neither is modified.
    method : {"estimate", "closest"}, default "estimate"
        "estimate": the spectral map (any pose, any units). "closest": for shapes that are
        already aligned in space (a scan and its simplified or remeshed copy): every target
        vertex goes to its closest point on the source surface (Open3D's RaycastingScene),
        kept exactly as a triangle and barycentric coordinates in the Correspondence; the
        spectral options below are then unused.
    align : bool, default False
        With ``method="closest"``: rigid pre-alignment by ICP for shapes that are almost
        aligned.
    partial : bool, default False
        The target is a part of the source (a one-sided scan, a cut), **in the same units**:
        partial functional maps (Rodolà et al. 2017: a slanted restriction map from the area
        ratio, fitted to local descriptors (diffused curvatures, WKS at common energies) with
        the orientation term, then a partial ZoomOut, a refinement by geodesic distances to
        the anchors the map keeps right and a second partial ZoomOut; see
        :func:`o3d_ofp.workflows.partial.match_partial_eigenbases`). ``quality.overlap``
        gives the estimated fraction of the source covered; ``method="partial"`` in the
        result. Meshes of more than 50 000 vertices are matched on coarse copies of about
        20 000 and the map is extended to every vertex, as in the full-shape case. Without
        it, a target that looks like a part of the source is flagged suspect.
    landmarks : (p, 2) array_like of int, optional
        Known (source vertex, target vertex) pairs; a few of them fix symmetric or
        ambiguous pairs.
    k_fit : int, default 29
        Size of the map fitted to the descriptors (the paper's K = 30); a second fit of 39
        functions is a further start (the map whose spectral embeddings align best after
        ZoomOut is kept; ``options["k_fit"]`` says which).
    zoomout_to : int, default 99
        Eigenfunctions the map is refined to (fewer only when a shape has fewer vertices).
    zoomout_subsample : int or None, default 2000
        ZoomOut iterates on this many farthest-point samples of each shape.
    descriptors : {"wks", "hks"}, default "wks"
        Descriptor family.
    w_orient : float, default 1.0
        Weight of the orientation-preserving term.
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components (see :func:`eigenbasis`).
    eigenbases : (EigenBasis, EigenBasis), optional
        Precomputed eigenbases with at least ``zoomout_to`` eigenfunctions each.

    Returns
    -------
    Correspondence
        ``p2p_21`` (n2,), the functional map, the options and ``quality`` (``coverage``,
        ``suspect`` and the measures behind it). A suspect map is warned about
        (:class:`OFPWarning`) with the likely causes and the fix; ``save(path)`` /
        ``Correspondence.load(path)`` keep it.

    References
    ----------
    .. [1] S. Melzi et al., "ZoomOut: Spectral Upsampling for Efficient Shape Correspondence",
       ACM TOG 38(6), 2019.
    """
    if method not in ("estimate", "closest"):
        raise ValueError(f"method must be 'estimate' or 'closest'; got {method!r}")
    if not isinstance(partial, bool):
        raise TypeError(f"partial must be True or False; got {partial!r}")
    source, target = read_if_path(source, "source"), read_if_path(target, "target")
    if partial and method != "estimate":
        raise ValueError("partial=True applies to method='estimate' (closest points need none)")
    if partial:
        from ..workflows.partial import check_partial_options

        check_partial_options(
            k_fit=k_fit,
            zoomout_to=zoomout_to,
            zoomout_subsample=zoomout_subsample,
            descriptors=descriptors,
            w_orient=w_orient,
        )
    elif method == "estimate":
        from ..workflows.matching import check_match_options

        check_match_options(
            k_fit=k_fit,
            zoomout_to=zoomout_to,
            zoomout_subsample=zoomout_subsample,
            descriptors=descriptors,
            w_orient=w_orient,
        )
    _check_pair(eigenbases, "eigenbases", EigenBasis, "ofp.eigenbasis")
    V1, F1 = as_arrays(source, name="source")
    V2, F2 = as_arrays(target, name="target")
    if method == "closest":
        if landmarks is not None:
            raise ValueError(
                "landmarks apply to method='estimate': a closest-point map has no use for them "
                "(align=True registers almost aligned shapes)"
            )
        return closest_correspondence(V1, F1, V2, faces_2=F2, align=align)
    if align:
        raise ValueError("align=True applies to method='closest' (the spectral map needs none)")
    options = {
        "landmarks": landmarks,
        "k_fit": k_fit,
        "zoomout_to": zoomout_to,
        "zoomout_subsample": zoomout_subsample,
        "descriptors": descriptors,
        "w_orient": w_orient,
    }
    if partial:
        for F, name in ((F1, "source"), (F2, "target")):
            if F is None:  # before any eigensolve (the workflow refuses it too)
                raise ValueError(
                    f"partial=True needs triangle meshes: the {name} is a point cloud (no "
                    "faces); mesh it first or match without partial=True"
                )
        from ..workflows.partial import check_partial_areas

        check_partial_areas(V1, F1, V2, F2)
    if eigenbases is None:
        return estimate_map_arrays(
            V1, F1, V2, F2, partial=partial, components=components, **options
        )
    eig_1, eig_2 = eigenbases
    for eig, V, name in ((eig_1, V1, "source"), (eig_2, V2, "target")):
        if eig.n_vertices != V.shape[0]:
            raise ValueError(
                f"the {name} eigenbasis has {eig.n_vertices} vertices but the {name} has "
                f"{V.shape[0]}: it belongs to another shape"
            )
        # the same count, another shape (swapped, another pose): said, as by the transfers
        warn_other_shape(eig, V, f"the {name} eigenbasis", f"the {name}")
    return estimate_map(eig_1, eig_2, partial=partial, **options)


def _check_pair(value: Any, name: str, kind: type, made_by: str) -> None:
    """Refuse a ``name=`` that is not a (source, target) pair of ``kind`` (None passes)."""
    if value is None:
        return
    if not (
        isinstance(value, tuple | list)
        and len(value) == 2
        and all(isinstance(v, kind) for v in value)
    ):
        raise TypeError(
            f"{name} must be a pair (source, target) of {kind.__name__} from {made_by}; got "
            f"{type(value).__name__}"
            + (f" of {len(value)}" if isinstance(value, tuple | list) else "")
        )


def transfer_colors(
    source: Any,
    target: Any,
    *,
    k1: int = 29,
    k2: int = 39,
    order: int = 2,
    preset: str | None = "ours",
    tol: float | None = None,
    correspondence: Correspondence | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    method: str = "p2p",
    via_basis: bool | None = None,
    eigenbases: tuple[Any, Any] | None = None,
    bases: tuple[Any, Any] | None = None,
    components: str = "auto",
    partial: bool = False,
    texture: Any = None,
) -> Any:
    """Transfer vertex colors from one Open3D geometry to another.

    Parameters
    ----------
    source, target : Open3D TriangleMesh or PointCloud (legacy or tensor)
        The shapes; neither is modified. The source must have vertex colors, or a texture (UVs
        and an image, as :func:`texture_colors` reads them): its colors then, per vertex, or at
        each target vertex's point on the source surface for an exact pull-back through a
        closest-point map (for any other per-vertex signal use the array-level
        :func:`o3d_ofp.transfer_function`).
    k1, k2 : int, default 29, 39
        Eigenfunctions multiplied on the source and the target (the paper's K = 30 / 40 for
        humans; order 3 with k ≈ 11-14 for other shapes).
    order : int, default 2
        Product order.
    preset, tol
        Orthogonalization threshold ("ours" = 1e-2 by default, "ours*" = 1e-9).
    correspondence : Correspondence, optional
        A map from :func:`match` (or ``Correspondence.load``).
    fmap_12, p2p_21, landmarks
        A known functional map, a known point-to-point map (target vertex → source vertex),
        or known (source, target) landmark pairs for the estimation. Without any of them the
        map is estimated by :func:`match`.
    method : {"p2p", "analytic"}
        Transfer matrix computation (see :func:`o3d_ofp.transfer_matrix`).
    via_basis : bool, optional
        Transfer through the OFP bases (the paper's transfer, robust to a noisy map) or pull
        the colors back exactly through the map. Default: exact pull-back for a closest-point
        map (``match(method="closest")``: at each target vertex's point on the source surface,
        or its nearest point of a point-cloud source), the bases otherwise. With
        ``via_basis=False`` and no map given, the map is estimated as :func:`match` does
        (``landmarks``, ``components``, ``partial`` and ``eigenbases`` apply), then pulled
        back.
    eigenbases : (EigenBasis, EigenBasis), optional
        Precomputed eigenbases of source and target (e.g. from cached bases); with an
        estimated map they should hold ~100 eigenfunctions for ZoomOut.
    bases : (OFPBasis, OFPBasis), optional
        Precomputed OFP bases (then ``k1``, ``k2``, ``order``, ``preset``, ``tol`` are unused).
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components in the eigenbases computed here (see
        :func:`eigenbasis`).
    partial : bool, default False
        The target is a part of the source (a one-sided scan, a cut) in the same units: the
        map estimated here is a partial one, as :func:`match` with ``partial=True`` makes it
        (both shapes triangle meshes; refused with a given map, which is used as it is).
    texture : str, os.PathLike, (H, W[, C]) ndarray or Open3D image, optional
        The source's texture image (rows top-down, as in an image file), for a source mesh
        with UVs whose image was not loaded (no material file next to it); when given, the
        colors transferred are this image's, read through the source's UVs, even where the
        source has vertex colors. Default: the source's vertex colors, else its own texture.

    Returns
    -------
    geometry
        A new geometry of the target's own kind (legacy or tensor, mesh or cloud) with every
        attribute of the target, colored with the transferred colors (clipped to [0, 1]).

    References
    ----------
    .. [1] G. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021. doi:10.1111/cgf.142645
    """
    if via_basis is not None and not isinstance(via_basis, bool):
        raise TypeError(f"via_basis must be True, False or None; got {via_basis!r}")
    check_method(method)
    _check_pair(eigenbases, "eigenbases", EigenBasis, "ofp.eigenbasis")
    _check_pair(bases, "bases", OFPBasis, "ofp.ofp_basis")
    source, target = read_if_path(source, "source"), read_if_path(target, "target")
    V1, F1 = as_arrays(source, name="source")
    V2, F2 = as_arrays(target, name="target")
    f = vertex_colors(source) if is_open3d_geometry(source) else None
    meshes = ("legacy_mesh", "tensor_mesh")
    if texture is not None and not (is_open3d_geometry(source) and geometry_kind(source) in meshes):
        raise TypeError(
            "texture= is the image of a source mesh with UVs; the source is a "
            f"{type(source).__name__}"
        )
    if texture is not None and not has_uvs(source):
        raise ValueError(
            "texture= is the image of a source mesh with UVs, and the source has no texture "
            "coordinates (for its vertex colors, leave texture= out)"
        )
    surface = None  # the source's texture, when its colors come from it
    if is_open3d_geometry(source) and (texture is not None or (f is None and has_uvs(source))):
        # its colors (a ValueError names missing UVs or a missing image)
        surface = mesh_texture(source, texture)
        f = surface.vertex_colors()
        logger.info(
            "transfer_colors: the colors of the source's %s are transferred",
            "texture (texture=)" if texture is not None else "texture (it has no vertex colors)",
        )
    if f is None and not is_open3d_geometry(source):
        raise TypeError(
            f"transfer_colors needs an Open3D geometry (or a file) as source, to read its "
            f"colors from; got {type(source).__name__} (for colors given as arrays, the "
            "array-level o3d_ofp.transfer_function)"
        )
    if f is None:
        stray = stray_colors(source)  # Open3D takes them for none (a trial's 100 colors)
        if stray is not None:
            raise ValueError(
                f"the source's vertex colors are not one per vertex: {stray}; give one color "
                "per vertex (Open3D ignores them otherwise)"
            )
        raise ValueError(
            "the source has neither vertex colors nor a texture to transfer (for another "
            "signal, the array-level o3d_ofp.transfer_function)"
        )
    # NaN colors (an in-memory mesh's) are refused here, before any eigensolve, by their name.
    what = "texture color" if surface is not None else "vertex color"
    f = as_signal(f, V1.shape[0], name=f"the source's {what} array")
    closest = check_correspondence(correspondence) is not None
    closest = closest and correspondence.method == "closest"
    if sum(x is not None for x in (correspondence, p2p_21, fmap_12)) > 1:  # on every path
        raise ValueError("give at most one of correspondence, p2p_21 and fmap_12")
    known = any(x is not None for x in (correspondence, p2p_21, fmap_12))
    exact = via_basis is False or (via_basis is None and closest)
    if exact:  # (the transfer through the bases checks it in prepare_transfer)
        check_partial_transfer(partial, known, V1, F1, V2, F2)  # before any eigensolve
        # Without a map one is estimated (landmarks, components and eigenbases then apply),
        # and pulled back.
        estimated = {} if known else {"landmarks": None, "components": "auto", "eigenbases": None}
        given = {"landmarks": landmarks, "components": components, "eigenbases": eigenbases}
        _refuse_basis_options(
            transfer_colors,
            "the exact pull-back (via_basis=False)" if via_basis is False
            else "the exact pull-back (the default with a closest-point map)",
            k1=k1, k2=k2, order=order, preset=preset, tol=tol, fmap_12=fmap_12,
            method=method, bases=bases, **{**given, **estimated},
        )  # fmt: skip
    if _has_texture(target):
        warn(
            logger,
            "transfer_colors: the target has a texture: the result keeps it "
            "beside the new vertex colors, and viewers and files (Open3D's OBJ and glTF "
            "writers) may show either; to bake the colors into its UV layout use "
            "o3d_ofp.transfer_texture(source, target, correspondence=...)",
        )
    if exact:
        if correspondence is None and p2p_21 is None:  # as match() estimates it
            correspondence = match(
                (V1, F1), (V2, F2), partial=partial, landmarks=landmarks,
                components=components, eigenbases=eigenbases,
            )  # fmt: skip
        if correspondence is None:
            correspondence = Correspondence(p2p_21=p2p_21, n_source=V1.shape[0])
        correspondence.check(V1.shape[0], V2.shape[0], source=V1, target=V2)
        logger.info("transfer_colors: exact pull-back through the %s map", correspondence.method)
        if surface is not None and correspondence.barycentric_21 is not None:
            # the texture at each target vertex's point on the source surface
            g = surface.sample(correspondence.faces_21, correspondence.barycentric_21)
        else:
            g = pull_back(f, correspondence, F1)
        return like_target(target, colors=np.clip(g, 0.0, 1.0))
    g = transfer_on_shapes(
        f,
        V1,
        F1,
        V2,
        F2,
        k1=k1,
        k2=k2,
        order=order,
        tol=tol,
        preset=preset,
        method=method,
        correspondence=correspondence,
        fmap_12=fmap_12,
        p2p_21=p2p_21,
        landmarks=landmarks,
        eigenbases=eigenbases,
        bases=bases,
        components=components,
        partial=partial,
    )
    return like_target(target, colors=np.clip(g, 0.0, 1.0))


def _refuse_basis_options(function: Callable[..., Any], transfer: str, **given: Any) -> None:
    """Refuse the options of ``function`` that a transfer without an OFP basis would ignore.

    ``given`` maps keywords to the values passed; those that differ from ``function``'s
    defaults are named in a ValueError (a trial's ``k1=20`` with a closest map was accepted and
    ignored; the command line refuses the same flags).
    """
    import inspect

    defaults = inspect.signature(function).parameters

    def default(name: str, value: Any) -> bool:
        by_default = defaults[name].default
        if by_default is None:
            return value is None
        return bool(np.isscalar(value) and value == by_default)

    def shown(value: Any) -> str:  # arrays and bases by their kind, not their contents
        return repr(value) if np.isscalar(value) else f"<{type(value).__name__}>"

    named = [f"{name}={shown(value)}" for name, value in given.items() if not default(name, value)]
    if named:
        raise ValueError(
            f"{function.__name__}: {', '.join(named)} {'does' if len(named) == 1 else 'do'} "
            f"not apply to {transfer}, which pulls the colors back through the map with no "
            f"OFP basis; drop {'it' if len(named) == 1 else 'them'}, or pass via_basis=True "
            "to transfer through the OFP bases"
        )


def _has_texture(geometry: Any) -> bool:
    """Tell whether an Open3D geometry is a mesh with UVs and a loaded texture image."""
    return (
        is_open3d_geometry(geometry) and has_uvs(geometry) and has_texture_image(geometry)
    )


def _large_enough(
    eigenbases: tuple[Any, Any],
    vertices: tuple[np.ndarray, np.ndarray],
    faces: tuple[Any, Any],
    need: tuple[int, int],
    components: str,
) -> tuple[Any, Any]:
    """Given eigenbases, each computed again (larger) when it has fewer than ``need``."""
    larger = []
    sides = zip(eigenbases, vertices, faces, need, ("source", "target"), strict=True)
    for eig, V, F, k, name in sides:
        if isinstance(eig, EigenBasis) and eig.k < k and eig.n_vertices == V.shape[0]:
            logger.info(
                "the %s eigenbasis has %d eigenfunctions, %d are needed: computing it again",
                name,
                eig.k,
                k,
            )
            eig = spectrum.eigenbasis(V, F, k=k, components=components)
        larger.append(eig)
    return larger[0], larger[1]


def transfer_detail(
    source: Any,
    target: Any,
    *,
    mode: str = "add",
    band: int = DETAIL_BAND,
    amount: float = 1.0,
    correspondence: Correspondence | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    k1: int = 29,
    k2: int = 39,
    order: int = 2,
    preset: str | None = "ours*",
    tol: float | None = None,
    k_low: int | None = None,
    eigenbases: tuple[Any, Any] | None = None,
    bases: tuple[Any, Any] | None = None,
    components: str = "auto",
    partial: bool = False,
) -> Any:
    """Give the target the source's geometric detail; return a new displaced geometry.

    The detail of a shape is what its coordinates have above its first ``band``
    Laplace-Beltrami eigenfunctions. It is carried through the map and re-applied in the
    target's local frames (fitted rotations between the two low-pass shapes), where the map
    is trusted; see :mod:`o3d_ofp.workflows.detail`.

    Parameters
    ----------
    source : Open3D TriangleMesh or PointCloud (legacy or tensor), or (vertices, faces)
        Shape with the detail.
    target : Open3D TriangleMesh or PointCloud (legacy or tensor), or (vertices, faces)
        Shape to displace. Neither input is modified. A point cloud without normals gets
        normals estimated by Open3D (used where the map is not trusted).
    mode : {"add", "replace-detail", "coordinates"}, default "add"
        "add": the target keeps its pose, its low-frequency shape and its own detail, and
        gains the source's detail on top (for a smooth target). "replace-detail": the
        target's own detail above ``band`` is replaced by the source's (a shape given itself
        with the identity map comes back unchanged). "coordinates": the paper's Fig. 13, the
        source's coordinates transferred with OFP bases replace the target's (the target
        takes the source's pose; ``k1``, ``k2``, ``order``, ``preset``, ``tol``, ``bases``
        are used only here). "replace" is the deprecated former name of "coordinates".
    band : int, default 30
        Eigenfunctions of the low band the detail is measured above: a count, so it means the
        same at every resolution and scale. Lower takes more of the source's shape (and
        pose), higher only its finer detail.
    amount : float, default 1.0
        Multiplies the transferred detail, in [0, 10].
    correspondence, fmap_12, p2p_21, landmarks
        The map, as in :func:`transfer_colors` (none: estimated by :func:`match`).
    k1, k2, order, preset, tol
        OFP bases of mode "coordinates" (default preset "ours*").
    k_low : int, optional
        Deprecated name of ``band`` (a ``DeprecationWarning``).
    eigenbases : (EigenBasis, EigenBasis), optional
        Precomputed eigenbases of source and target: with at least ``band`` eigenfunctions
        (~100 for an estimated map); a smaller one is computed again, larger.
    bases : (OFPBasis, OFPBasis), optional
        Precomputed OFP bases for mode "coordinates" (ignored by the other modes).
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components in the eigenbases computed here (see
        :func:`eigenbasis`).
    partial : bool, default False
        The target is a part of the source (a one-sided scan, a cut) in the same units: the
        map estimated here is a partial one, as :func:`match` with ``partial=True`` makes it
        (both shapes triangle meshes; refused with a given map, which is used as it is).
        The detail is then measured on the region of the source the part covers.

    Returns
    -------
    geometry
        A new geometry of the target's own kind with moved vertices (every other attribute of
        the target kept).

    Raises
    ------
    ValueError, TypeError
        For a bad ``mode``, ``band``, ``amount``, ``k_low`` or ``partial`` (``partial=True``
        with a given map, a point cloud, or a target that cannot be a part of the source; the
        message names the keyword), before any eigensolve.
    """
    if k_low is not None:
        warnings.warn("k_low is deprecated; use band", DeprecationWarning, stacklevel=2)
        band = k_low
    mode, band, amount = check_detail_options(
        mode=mode, band=band, amount=amount, names={"band": "band" if k_low is None else "k_low"}
    )
    _check_pair(eigenbases, "eigenbases", EigenBasis, "ofp.eigenbasis")
    _check_pair(bases, "bases", OFPBasis, "ofp.ofp_basis")
    source, target = read_if_path(source, "source"), read_if_path(target, "target")
    V1, F1 = as_arrays(source, name="source")
    V2, F2 = as_arrays(target, name="target")
    if mode != "coordinates":  # the band is a count of eigenfunctions of both shapes
        check_int(
            band,
            name="band" if k_low is None else "k_low",
            minimum=1,
            maximum=max(1, min(V1.shape[0], V2.shape[0]) - 2),
        )
    if mode == "coordinates":
        for value, name in ((k1, "k1"), (k2, "k2"), (order, "order")):
            check_int(value, name=name, minimum=1)
        if bases is None:
            check_basis_options(order, tol, preset)  # before the eigenbases below
        if eigenbases is not None and bases is None:
            eigenbases = _large_enough(eigenbases, (V1, V2), (F1, F2), (k1, k2), components)
        moved = transfer_on_shapes(
            lambda eig_1: eig_1.vertices,
            V1,
            F1,
            V2,
            F2,
            k1=k1,
            k2=k2,
            order=order,
            tol=tol,
            preset=preset,
            correspondence=correspondence,
            fmap_12=fmap_12,
            p2p_21=p2p_21,
            landmarks=landmarks,
            eigenbases=eigenbases,
            bases=bases,
            components=components,
            partial=partial,
        )
        part = partial or (correspondence is not None and correspondence.method == "partial")
        # A full map estimated here (or given as match()'s) must give the source's area; a
        # map of another kind (an array, identity, closest points) may be onto a part.
        estimated = correspondence.method == "estimate" if correspondence is not None else (
            p2p_21 is None and fmap_12 is None
        )  # fmt: skip
        check_coordinates_area(
            V1, F1, moved, F2, part=V2 if part else None, target=None if estimated else V2
        )
        return like_target(target, vertices=moved)
    need = max(band, ROTATION_K)
    if eigenbases is not None:  # too small for the band: computed again, larger
        eigenbases = _large_enough(eigenbases, (V1, V2), (F1, F2), (need, need), components)
    normals_1 = point_normals(source, V1) if F1 is None and is_open3d_geometry(source) else None
    normals_2 = point_normals(target, V2) if F2 is None and is_open3d_geometry(target) else None
    eig_1, eig_2, correspondence = prepare_transfer(
        V1,
        F1,
        V2,
        F2,
        k1=need,
        k2=need,
        correspondence=correspondence,
        fmap_12=fmap_12,
        p2p_21=p2p_21,
        landmarks=landmarks,
        eigenbases=eigenbases,
        components=components,
        partial=partial,
    )
    if fmap_12 is not None:
        p2p_21 = p2p_from_fmap(fmap_12, eig_1, eig_2)
    moved = transfer_detail_frames(
        eig_1,
        eig_2,
        p2p_21=p2p_21,
        correspondence=correspondence,
        mode=mode,
        band=band,
        amount=amount,
        normals_1=normals_1,
        normals_2=normals_2,
    )
    return like_target(target, vertices=moved)


def filter_geometry(
    geometry: Any,
    *,
    smooth: float | None = None,
    sharpen: float | None = None,
    keep_volume: bool = True,
    gains: Any = None,
    k: int = 14,
    order: int = 3,
    preset: str | None = "ours*",
    tol: float | None = None,
    basis: Any = None,
    components: str = "auto",
) -> Any:
    """Smooth or sharpen the vertex coordinates of a mesh or a point cloud.

    ``smooth`` alone returns the low-pass shape (:func:`o3d_ofp.filtering.smooth_coordinates`,
    a Butterworth low-pass over the whole spectrum of the Laplacian, nothing of the input
    above the cut added back, the enclosed volume kept). ``sharpen`` multiplies the detail
    smaller than ``smooth`` by ``1 + sharpen`` (:func:`o3d_ofp.filtering.sharpen_coordinates`).
    ``gains`` filters instead the coefficients in an OFP basis (the paper's Figs. 14-15).

    Parameters
    ----------
    geometry : Open3D TriangleMesh or PointCloud (legacy or tensor)
        Input; not modified.
    smooth : float, optional
        Smoothing radius as a fraction of √area, in [0, 0.25]: detail smaller than about
        ``smooth · √area`` is removed, the same at every scale and resolution (0.01, the
        default with ``sharpen``, removes noise of about 0.5 % of the bounding-box diagonal
        on a human or the bunny). With ``sharpen``: the size of the detail enhanced.
    sharpen : float, optional
        Detail gain in [0, 2] (the detail is multiplied by ``1 + sharpen``; beyond 2
        triangles start turning over, so larger values are refused).
    keep_volume : bool, default True
        Scale the result about its centroid to the input's enclosed volume (a point cloud:
        its spread).
    gains : callable or (q,) array_like, optional
        Instead of ``smooth`` / ``sharpen``: gains of the OFP basis functions, see
        :func:`o3d_ofp.filtering.spectral_filter` (e.g. ``smooth_gains(5)``).
    k, order, preset, tol
        The OFP basis for ``gains`` (the paper uses order 3 on the first 15 eigenfunctions:
        ``k=14``).
    basis : OFPBasis or EigenBasis, optional
        A precomputed basis of this geometry (then ``k``, ``order``, ``preset``, ``tol`` are
        unused; ``gains`` needs an OFPBasis). One computed on another shape with the same
        vertex count gives an ``OFPWarning``.
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components in the basis computed here (see
        :func:`eigenbasis`).

    Returns
    -------
    open3d.geometry.TriangleMesh or open3d.geometry.PointCloud
        A new geometry of the input's own kind with filtered vertex positions (every other
        attribute kept).

    Raises
    ------
    ValueError
        For none or a wrong combination of ``smooth`` / ``sharpen`` / ``gains``, or a value
        outside its range (the message names the keyword), before any eigensolve.
    """
    if gains is not None and (smooth is not None or sharpen is not None):
        raise ValueError("give gains alone, or smooth and/or sharpen (not both)")
    if gains is None and smooth is None and sharpen is None:
        raise ValueError("give smooth (a radius in [0, 0.25]), sharpen (in [0, 2]) or gains")
    if gains is None:
        smooth = check_amount(DEFAULT_SMOOTH if smooth is None else smooth, "smooth", MAX_SMOOTH)
        if sharpen is not None:
            sharpen = check_amount(sharpen, "sharpen", MAX_SHARPEN)
    if not isinstance(keep_volume, bool):
        raise TypeError(f"keep_volume must be True or False; got {keep_volume!r}")
    geometry = read_if_path(geometry, "geometry")
    V, F = as_arrays(geometry, name="geometry")  # a (vertices, faces) tuple too
    if basis is not None and basis.n_vertices != V.shape[0]:
        raise ValueError(
            f"basis has {basis.n_vertices} vertices but the geometry has {V.shape[0]}: it "
            "belongs to another shape"
        )
    if basis is not None:
        warn_other_shape(
            basis.eig if isinstance(basis, OFPBasis) else basis, V, "basis", "the geometry"
        )
    if gains is None:
        # The low-pass needs only the Laplacian (and the cleaning) of an eigenbasis.
        eig = basis if basis is not None else spectrum.eigenbasis(V, F, k=1, components=components)
        if sharpen is None:
            X = smooth_coordinates(eig, V, smooth=smooth, keep_volume=keep_volume)
        else:
            X = sharpen_coordinates(eig, V, sharpen=sharpen, smooth=smooth, keep_volume=keep_volume)
        return like_target(geometry, vertices=X)
    if basis is None:
        B = ofp_basis(
            spectrum.eigenbasis(V, F, k=k, components=components),
            order=order,
            preset=preset,
            tol=tol,
        )
    elif not isinstance(basis, OFPBasis):
        raise TypeError(f"gains need an OFPBasis as basis; got {type(basis).__name__}")
    else:
        B = basis
    return like_target(geometry, vertices=spectral_filter(B, V, gains))
