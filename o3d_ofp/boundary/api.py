"""The geometry-level API: Open3D geometries (or array tuples) in, new geometries out.

Each function converts its inputs with :mod:`o3d_ofp.boundary.convert`, plans the job with
:func:`o3d_ofp.workflows.plan.plan_pair`, runs it with :func:`~o3d_ofp.workflows.plan.prepare`
and returns a new geometry of the target's own kind; the inputs are never modified. The
closest-point map, which needs Open3D's ray casting, is made here.
"""

from __future__ import annotations

import dataclasses
import logging
import numbers
from typing import Any

import numpy as np

from ..core import spectrum
from ..core._validation import as_signal
from ..core._warnings import warn
from ..core.basis import OFPBasis, ofp_basis
from ..core.filtering import (
    DEFAULT_SMOOTH,
    MAX_SHARPEN,
    MAX_SMOOTH,
    check_amount,
    sharpen_coordinates,
    smooth_coordinates,
    spectral_filter,
)
from ..core.spectrum import DEFAULT_K, EigenBasis
from ..core.wording import OptionError, Said
from ..workflows import cache
from ..workflows.detail import check_coordinates_area, transfer_detail_frames
from ..workflows.maps import Correspondence, check_correspondence, warn_other_shape
from ..workflows.options import (
    COMPONENTS,
    BasisOptions,
    DetailOptions,
    MatchOptions,
    check_bool,
    check_choice,
    moved_keywords,
)
from ..workflows.pipeline import carry, pull_back
from ..workflows.plan import plan_pair, prepare
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
    "match_options",
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
            number = isinstance(faces, numbers.Integral) and not isinstance(faces, bool)
            hint = (f" (got {faces}: the eigenfunction count is keyword-only, k={faces})"
                    if number else "")  # fmt: skip
            raise ValueError(f"faces must be None when {name} is an Open3D geometry{hint}")
        return geometry_to_arrays(shape, name=name)
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
    k: int = DEFAULT_K,
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
    weld_tolerance : float or None, default 1e-9
        Relative distance (to the bounding box's largest side) under which vertices are welded.
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components (:func:`o3d_ofp.clean_shape`): "auto" keeps
        the largest when it holds ≥ 90 % of the area, else raises.
    mollify_factor, n_neighbors : float, int
        Passed to :func:`o3d_ofp.laplacian` (default 1e-5; 30 neighbours per point of a point
        cloud).
    maxiter : int, optional
        Bound on the Lanczos restarts per attempt (default ``max(1000, 10 (k + 1))``).
    clamp_k : bool, default False
        Reduce a ``k`` the cleaned shape cannot hold to ``n − 1`` (with a warning), not raise.
    factorization : {"auto", "cholmod", "superlu"}, default "auto"
        Sparse factorization of ``L − σM`` for shift-invert: CHOLMOD's supernodal Cholesky
        (from the ``cholespy`` wheels) when it can be imported, else SciPy's SuperLU (logged).

    Returns
    -------
    EigenBasis
        Eigenvalues ``(k+1,)``, M-orthonormal eigenvectors ``(n, k+1)`` with the constant first,
        the lumped mass and the stiffness, on the input's n vertices.

    References
    ----------
    .. [1] F. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021. doi:10.1111/cgf.142645

    Examples
    --------
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> eig = ofp.eigenbasis(sphere, k=8)
    >>> eig.evecs.shape  # 182 vertices, the constant and 8 eigenfunctions
    (182, 9)
    >>> [round(float(x)) for x in eig.evals[:4]]  # a unit sphere's: l (l + 1)
    [0, 2, 2, 2]
    """
    V, F = as_arrays(mesh_or_vertices, faces, name="mesh_or_vertices")
    return spectrum.eigenbasis(
        V, F, k=k, weld_tolerance=weld_tolerance, components=components,
        mollify_factor=mollify_factor, n_neighbors=n_neighbors, maxiter=maxiter, clamp_k=clamp_k,
        factorization=factorization,
    )  # fmt: skip


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

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> digest = ofp.shape_digest(sphere)
    >>> len(digest)
    32
    >>> digest == ofp.shape_digest(np.asarray(sphere.vertices), np.asarray(sphere.triangles))
    True
    >>> digest == ofp.shape_digest(sphere, components="largest")  # another cleaning option
    False
    """
    V, F = as_arrays(mesh_or_vertices, faces, name="mesh_or_vertices")
    return spectrum.shape_digest(
        V, F, weld_tolerance=weld_tolerance, components=components,
        mollify_factor=mollify_factor, n_neighbors=n_neighbors,
    )  # fmt: skip


def cached_basis(
    mesh_or_vertices: Any,
    faces: Any = None,
    *,
    k: int = DEFAULT_K,
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

    Examples
    --------
    >>> import os
    >>> import tempfile
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> with tempfile.TemporaryDirectory() as cache:
    ...     B = ofp.cached_basis(sphere, k=8, cache_dir=cache)  # computed, then written
    ...     again = ofp.cached_basis(sphere, k=8, cache_dir=cache)  # read back
    ...     files = os.listdir(cache)
    >>> again.size == B.size, len(files)
    (True, 1)
    """
    V, F = as_arrays(mesh_or_vertices, faces, name="mesh_or_vertices")
    return cache.cached_basis(
        V, F, k=k, order=order, tol=tol, preset=preset, cache_dir=cache_dir,
        weld_tolerance=weld_tolerance, components=components, mollify_factor=mollify_factor,
        n_neighbors=n_neighbors,
    )  # fmt: skip


def match_options(options: MatchOptions | None = None, **keywords: Any) -> MatchOptions:
    """Return ``options`` with the keywords given (those not at their defaults) over it.

    The one place :func:`match`'s keywords and its ``options`` object are joined.
    """
    base = MatchOptions() if options is None else options
    if not isinstance(base, MatchOptions):
        raise OptionError(
            "options", f"must be an o3d_ofp.MatchOptions; got {type(base).__name__}"
        )
    defaults = MatchOptions()
    given = {
        name: value for name, value in keywords.items()
        if (value is not None if name == "landmarks" else value != getattr(defaults, name))
    }  # fmt: skip
    return dataclasses.replace(base, **given) if given else base


@moved_keywords("k_fit", "zoomout_to", "zoomout_subsample", "descriptors", "w_orient")
def match(
    source: Any,
    target: Any,
    *,
    method: str = "estimate",
    align: bool = False,
    partial: bool = False,
    landmarks: Any = None,
    components: str = "auto",
    eigenbases: tuple[EigenBasis, EigenBasis] | None = None,
    options: MatchOptions | None = None,
    progress: Any = None,
) -> Correspondence:
    """Find, for every target vertex, its source vertex: one call, any units, with a verdict.

    Descriptor fit (WKS, Laplacian and descriptor commutativity, orientation-preserving term)
    then ZoomOut to 100 eigenfunctions and the point map, all on unit-area copies of the
    shapes: the map does not change when either shape is scaled, moved or rotated (except
    with ``MatchOptions(same_frame=True)``, which reads the shapes' given orientation).

    Parameters
    ----------
    source, target : Open3D TriangleMesh or PointCloud (legacy or tensor), a (vertices, faces)
        tuple of arrays (faces None for points), or a file path
        The shapes; neither is modified.
    method : {"estimate", "closest"}, default "estimate"
        "estimate": the spectral map (any pose, any units). "closest": for shapes that are
        already aligned in space (a scan and its simplified or remeshed copy): every target
        vertex goes to its closest point on the source surface (Open3D's RaycastingScene),
        kept exactly as a triangle and barycentric coordinates in the Correspondence.
    align : bool, default False
        With ``method="closest"``: rigid pre-alignment by ICP for shapes that are almost
        aligned.
    partial : bool, default False
        The target is a part of the source (a one-sided scan, a cut), **in the same units**:
        partial functional maps (see :mod:`o3d_ofp.workflows.partial`); ``quality.overlap``
        gives the estimated fraction of the source covered; ``method="partial"`` in the
        result. Without it, a target that looks like a part of the source is flagged suspect.
    landmarks : (p, 2) array_like of int, optional
        Known (source vertex, target vertex) pairs; a few of them fix symmetric or
        ambiguous pairs, and they drive the refinement (see
        :func:`o3d_ofp.zoomout_refine`): 5-6 well-spread ones map shapes that are
        not near-isometric (a gorilla onto a human, ``scripts/eval_nonisometric.py``). The
        map keeps each pair exactly; its quality notes how far the estimate had put them.
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components (see :func:`eigenbasis`).
    eigenbases : (EigenBasis, EigenBasis), optional
        Precomputed eigenbases (computed again, larger, when they hold fewer eigenfunctions
        than the estimation needs: ``options.zoomout_to``); with them the map is estimated at
        full resolution, also above the dense path's size (slower, no coarse copies).
    options : MatchOptions, optional
        All of the above and the estimation's own settings (fit size ``k_fit``, ZoomOut's
        ``zoomout_to`` and ``zoomout_subsample``, ``descriptors``, ``w_orient``); the keywords
        given here, when not at their defaults, replace its fields.
    progress : callable, optional
        ``progress(stage, fraction_done)`` of a long estimation (default: logged at INFO every
        few seconds).

    Returns
    -------
    Correspondence
        ``p2p_21`` (n2,), the functional map, the options and ``quality`` (``coverage``,
        ``suspect`` and the measures behind it). A suspect map is warned about
        (:class:`OFPWarning`) with the likely causes and the fix; ``save(path)`` /
        ``Correspondence.load(path)`` keep it.

    Notes
    -----
    Meshes of more than 50 000 vertices are matched on coarse copies of about 20 000 and the
    map is extended to every vertex (:mod:`o3d_ofp.workflows.dense`).

    References
    ----------
    .. [1] S. Melzi et al., "ZoomOut: Spectral Upsampling for Efficient Shape Correspondence",
       ACM TOG 38(6), 2019.

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> ellipsoid = o3d.geometry.TriangleMesh(sphere)
    >>> xyz = np.asarray(sphere.vertices) * [1.0, 0.7, 0.5]
    >>> ellipsoid.vertices = o3d.utility.Vector3dVector(xyz)
    >>> moved = o3d.geometry.TriangleMesh(ellipsoid)
    >>> _ = moved.rotate(moved.get_rotation_matrix_from_xyz((0.3, 0.2, 0.1)), center=(0, 0, 0))
    >>> _ = moved.translate((2.0, 0.0, 0.0))
    >>> corr = ofp.match(ellipsoid, moved)
    >>> corr.p2p_21.shape, corr.method
    ((182,), 'estimate')
    >>> corr.quality.suspect, corr.quality.coverage > 0.5
    (False, True)
    """
    opts = match_options(
        options, method=method, align=align, partial=partial, landmarks=landmarks,
        components=components,
    )  # fmt: skip
    _check_pair(eigenbases, "eigenbases", EigenBasis, "EigenBasis from ofp.eigenbasis")
    V1, F1 = as_arrays(source, name="source")
    V2, F2 = as_arrays(target, name="target")
    plan = plan_pair(V1, F1, V2, F2, task="map", match=opts, eigenbases=eigenbases or (None, None))
    if plan.estimator == "closest":
        return closest_correspondence(V1, F1, V2, faces_2=F2, align=opts.align)
    prepared = prepare(
        plan, V1, F1, V2, F2, match=opts, eigenbases=eigenbases or (None, None), progress=progress
    )
    return prepared.correspondence


def _check_pair(value: Any, name: str, kinds: type | tuple[type, ...], what: str) -> None:
    """Refuse a ``name=`` that is not a (source, target) pair of ``kinds`` (None passes)."""
    sized = isinstance(value, tuple | list)
    if value is None or (sized and len(value) == 2 and all(isinstance(v, kinds) for v in value)):
        return
    raise OptionError(name, f"must be a pair (source, target) of {what}; got "
                      f"{type(value).__name__}" + (f" of {len(value)}" if sized else ""))


def _bases(value: Any) -> tuple[tuple[Any, Any], tuple[Any, Any]]:
    """(eigenbases, OFP bases) from a transfer's ``bases=``: a pair of either kind, or None."""
    _check_pair(value, "bases", (EigenBasis, OFPBasis, type(None)), "OFPBasis (ofp.ofp_basis) or "
                "EigenBasis (ofp.eigenbasis), either None")  # fmt: skip
    value = (None, None) if value is None else value
    eigs = tuple(v if isinstance(v, EigenBasis) else None for v in value)
    ofps = tuple(v if isinstance(v, OFPBasis) else None for v in value)
    return eigs, ofps  # type: ignore[return-value]


def _source_colors(source: Any, V1: np.ndarray, texture: Any) -> tuple[np.ndarray, Any]:
    """Return the source's colors per vertex, and its texture when they come from it."""
    if not is_open3d_geometry(source):
        raise OptionError(
            "source", f"must be an Open3D geometry (or a file) to read its colors from; got "
            f"{type(source).__name__} (for colors given as arrays, the array-level "
            "o3d_ofp.transfer_function)",
        )  # fmt: skip
    meshes = ("legacy_mesh", "tensor_mesh")
    if texture is not None and geometry_kind(source) not in meshes:
        raise OptionError(
            "texture", f"= is the image of a source mesh with UVs; the source is a "
            f"{type(source).__name__}",
        )  # fmt: skip
    if texture is not None and not has_uvs(source):
        raise OptionError(
            "texture", "= is the image of a source mesh with UVs, and the source has no texture "
            "coordinates (for its vertex colors, leave texture= out)",
        )  # fmt: skip
    f, surface = vertex_colors(source), None
    if texture is not None or (f is None and has_uvs(source)):
        surface = mesh_texture(source, texture)  # a ValueError names missing UVs or image
        f = surface.vertex_colors()
        logger.info(
            "transfer_colors: the colors of the source's %s are transferred",
            "texture (texture=)" if texture is not None else "texture (it has no vertex colors)",
        )
    if f is None:
        stray = stray_colors(source)  # Open3D takes them for none
        raise ValueError(
            f"the source's vertex colors are not one per vertex: {stray}; give one color per "
            "vertex (Open3D ignores them otherwise)" if stray is not None else
            "the source has neither vertex colors nor a texture to transfer (for another "
            "signal, the array-level o3d_ofp.transfer_function)"
        )  # fmt: skip
    what = "texture color" if surface is not None else "vertex color"
    return as_signal(f, V1.shape[0], name=f"the source's {what} array"), surface


@moved_keywords(
    "k1", "k2", "order", "preset", "tol", "p2p_21", "fmap_12", "landmarks", "partial", "components",
    "method", "eigenbases",
)
def transfer_colors(
    source: Any,
    target: Any,
    *,
    correspondence: Correspondence | None = None,
    bases: tuple[Any, Any] | None = None,
    options: BasisOptions | None = None,
    via_basis: bool | None = None,
    texture: Any = None,
) -> Any:
    """Transfer vertex colors from one Open3D geometry to another.

    Parameters
    ----------
    source, target : Open3D TriangleMesh or PointCloud (legacy or tensor), or a file path
        The shapes; neither is modified. The source must have vertex colors, or a texture (UVs
        and an image, as :func:`texture_colors` reads them): its colors then, per vertex, or at
        each target vertex's point on the source surface for an exact pull-back through a
        closest-point map (for any other per-vertex signal use the array-level
        :func:`o3d_ofp.transfer_function`).
    correspondence : Correspondence, optional
        The map: from :func:`match` (with landmarks, ``partial=True``, ... as needed),
        ``Correspondence.load``, or one the caller brings
        (:meth:`Correspondence.from_p2p`, :meth:`Correspondence.from_fmap`). Default:
        estimated as :func:`match` does with its defaults.
    bases : (OFPBasis or EigenBasis, OFPBasis or EigenBasis), optional
        Precomputed bases of source and target (either may be None): OFP bases are used as
        they are; eigenbases serve the bases built here (computed again, larger, when they
        hold too few eigenfunctions).
    options : BasisOptions, optional
        How the OFP bases are built (default ``BasisOptions()``: order 2 on the paper's 29 /
        39 eigenfunctions, threshold "ours"; ``k1=k2=14, order=3`` suits other shapes than
        humans).
    via_basis : bool, optional
        Transfer through the OFP bases (the paper's transfer, robust to a noisy map) or pull
        the colors back exactly through the map. Default: exact pull-back for a closest-point
        map (``match(method="closest")``: at each target vertex's point on the source surface,
        or its nearest point of a point-cloud source), the bases otherwise.
    texture : str, os.PathLike, (H, W[, C]) ndarray or Open3D image, optional
        The source's texture image (rows top-down, as in an image file), for a source mesh
        with UVs whose image was not loaded; when given, the colors transferred are this
        image's, read through the source's UVs, even where the source has vertex colors.

    Returns
    -------
    geometry
        A new geometry of the target's own kind (legacy or tensor, mesh or cloud) with every
        attribute of the target, colored with the transferred colors (clipped to [0, 1]).

    References
    ----------
    .. [1] F. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021. doi:10.1111/cgf.142645

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> source = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> z = np.asarray(source.vertices)[:, 2]
    >>> colors = np.column_stack([(1 + z) / 2, np.full_like(z, 0.5), (1 - z) / 2])
    >>> source.vertex_colors = o3d.utility.Vector3dVector(colors)
    >>> target = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> _ = target.translate((2.0, 0.0, 0.0))
    >>> corr = ofp.Correspondence.from_p2p(np.arange(182), source, target)
    >>> out = ofp.transfer_colors(source, target, correspondence=corr)
    >>> np.asarray(out.vertex_colors).shape
    (182, 3)
    >>> bool(np.abs(np.asarray(out.vertex_colors) - colors).max() < 0.05)
    True
    """
    source, target = read_if_path(source, "source"), read_if_path(target, "target")
    V1, F1 = as_arrays(source, name="source")
    V2, F2 = as_arrays(target, name="target")
    f, surface = _source_colors(source, V1, texture)
    check_correspondence(correspondence)
    eigs, ofps = _bases(bases)
    plan = plan_pair(
        V1, F1, V2, F2, task="colors", bases=options, given=correspondence, given_bases=ofps,
        eigenbases=eigs, via_basis=via_basis,
    )  # fmt: skip
    if plan.exact and bases is not None:
        raise OptionError("bases", "do not apply to the exact pull-back (no OFP basis)")
    if is_open3d_geometry(target) and has_uvs(target) and has_texture_image(target):
        warn(logger, Said(
            "transfer_colors: the target has a texture: the result keeps it beside the new "
            "vertex colors, and viewers and files (Open3D's OBJ and glTF writers) may show "
            "either; to bake the colors into its UV layout use o3d_ofp.transfer_texture(source, "
            "target, correspondence=...)", {}, "target_texture",
        ))  # fmt: skip
    prepared = prepare(
        plan, V1, F1, V2, F2, given=correspondence, eigenbases=eigs, bases=ofps
    )
    corr = prepared.correspondence
    if not plan.exact:
        g = carry(f, plan, prepared)
    elif surface is not None and corr.barycentric_21 is not None:
        g = surface.sample(corr.faces_21, corr.barycentric_21)  # at the exact surface point
    else:
        logger.info("transfer_colors: exact pull-back through the %s map", corr.method)
        g = pull_back(f, corr, F1)
    return like_target(target, colors=np.clip(g, 0.0, 1.0))


@moved_keywords(
    "k1", "k2", "order", "preset", "tol", "p2p_21", "fmap_12", "landmarks", "partial", "components",
    "k_low", "eigenbases",
)
def transfer_detail(
    source: Any,
    target: Any,
    *,
    correspondence: Correspondence | None = None,
    mode: str = "add",
    band: int | None = None,
    amount: float = 1.0,
    bases: tuple[Any, Any] | None = None,
    options: BasisOptions | None = None,
) -> Any:
    """Give the target the source's geometric detail; return a new displaced geometry.

    By default the detail is what the target lacks, whatever smoothed it: the source's
    low-pass the target resembles most is found (heat low-passes compared through the map,
    :func:`o3d_ofp.workflows.detail.calibrate_detail`; a region smoothed more than the rest,
    as by a sculpting brush, gets its own longer one), and the source's detail above it is
    carried through the map and re-applied in the target's local frames (fitted rotations
    between the low-pass and the target), where the target lacks it and the map is trusted;
    see :mod:`o3d_ofp.workflows.detail`.

    Parameters
    ----------
    source : Open3D TriangleMesh or PointCloud (legacy or tensor), (vertices, faces) or a path
        Shape with the detail.
    target : Open3D TriangleMesh or PointCloud (legacy or tensor), (vertices, faces) or a path
        Shape to displace. Neither input is modified. A point cloud without normals gets
        normals estimated by Open3D (used where the map is not trusted).
    correspondence : Correspondence, optional
        The map, as in :func:`transfer_colors` (a partial map from ``match(partial=True)``:
        the detail is then measured on the region of the source the part covers).
    mode : {"add", "replace-detail", "coordinates"}, default "add"
        "add": the target keeps its pose, its shape and its own detail, and gains the detail
        it lacks (a target as detailed as the source gets almost nothing, and a warning says
        so; the map must be precise to an edge: through an estimated map that finds little
        lacking, a warning asks for a map you trust). "replace-detail": the target's own
        detail above the same low-pass is replaced by the source's everywhere (a shape given
        itself with the identity map comes back unchanged). "coordinates": the paper's Fig.
        13, the source's coordinates transferred with OFP bases replace the target's (the
        target takes the source's pose and surface: for aligned copies with a closest-point
        map; ``bases`` and ``options`` apply only here, threshold "ours*" by default).
        "replace" is the deprecated former name of "coordinates".
    band : int, optional
        None (default): calibrated, as above. An int: the detail is what the coordinates have
        above their first ``band`` Laplace-Beltrami eigenfunctions, added everywhere
        whatever the target has (an expert's override: a count, so it means the same at
        every resolution and scale; lower takes more of the source's shape and pose).
    amount : float, default 1.0
        Multiplies the transferred detail, in [0, 10].
    bases : (EigenBasis or OFPBasis, EigenBasis or OFPBasis), optional
        Precomputed bases of source and target, as in :func:`transfer_colors` (with ``band``
        given, an eigenbasis with fewer than ``band`` eigenfunctions is computed again,
        larger).
    options : BasisOptions, optional
        The OFP bases of mode "coordinates" (default order 2 on 29 / 39 eigenfunctions,
        "ours*").

    Returns
    -------
    geometry
        A new geometry of the target's own kind with moved vertices (every other attribute of
        the target kept).

    Raises
    ------
    ValueError, TypeError
        For a bad ``mode``, ``band`` or ``amount`` (the message names the keyword), before any
        eigensolve.

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> target = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> xyz = np.asarray(target.vertices)
    >>> angle = np.arctan2(xyz[:, 1], xyz[:, 0])
    >>> ripples = 1 + 0.03 * np.sin(8 * angle) * np.sin(np.pi * xyz[:, 2])
    >>> detailed = xyz * ripples[:, None]
    >>> source = o3d.geometry.TriangleMesh(target)
    >>> source.vertices = o3d.utility.Vector3dVector(detailed)
    >>> corr = ofp.Correspondence.from_p2p(np.arange(182), source, target)
    >>> out = ofp.transfer_detail(source, target, correspondence=corr)
    >>> new = np.asarray(out.vertices)
    >>> new.shape  # the target, given the source's ripples
    (182, 3)
    >>> bool(np.linalg.norm(new - detailed) < 0.5 * np.linalg.norm(xyz - detailed))
    True
    """
    detail = DetailOptions(mode=mode, band=band, amount=amount)
    check_correspondence(correspondence)
    eigs, ofps = _bases(bases)
    source, target = read_if_path(source, "source"), read_if_path(target, "target")
    V1, F1 = as_arrays(source, name="source")
    V2, F2 = as_arrays(target, name="target")
    plan = plan_pair(
        V1, F1, V2, F2, task="detail", detail=detail, bases=options, given=correspondence,
        given_bases=ofps, eigenbases=eigs,
    )  # fmt: skip
    prepared = prepare(plan, V1, F1, V2, F2, given=correspondence, eigenbases=eigs, bases=ofps)
    corr = prepared.correspondence
    if detail.mode == "coordinates":
        assert prepared.eig_1 is not None
        moved = carry(prepared.eig_1.vertices, plan, prepared)
        check_coordinates_area(
            V1, F1, moved, F2, part=V2 if corr.method == "partial" else None,
            target=None if corr.method == "estimate" else V2,  # a map that may be onto a part
        )  # fmt: skip
        return like_target(target, vertices=moved)
    normals_1 = point_normals(source, V1) if F1 is None and is_open3d_geometry(source) else None
    normals_2 = point_normals(target, V2) if F2 is None and is_open3d_geometry(target) else None
    moved = transfer_detail_frames(
        prepared.eig_1, prepared.eig_2, correspondence=corr, mode=detail.mode, band=detail.band,
        amount=detail.amount, normals_1=normals_1, normals_2=normals_2,
    )  # fmt: skip
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

    ``smooth`` alone returns the low-pass shape (:func:`o3d_ofp.core.filtering.smooth_coordinates`,
    a Butterworth low-pass over the whole spectrum of the Laplacian, nothing of the input
    above the cut added back, the enclosed volume kept; the graph (umbrella) Laplacian of the
    mesh's edges, robust to noise). ``sharpen`` multiplies the detail smaller than ``smooth``
    by ``1 + sharpen`` (:func:`o3d_ofp.core.filtering.sharpen_coordinates`); that detail is
    measured above the cotangent Laplacian's low-pass, not above the umbrella one ``smooth``
    alone returns, so against the latter the gain is smaller.
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
        Detail gain in [0, 2] (the detail is multiplied by ``1 + sharpen``). Up to 2 at most
        0.13 % of the triangles turned over on the measured meshes (FAUST 093 at 1: one
        triangle); beyond 2 more do, so larger values are refused.
    keep_volume : bool, default True
        Scale the result about its centroid to the input's enclosed volume (a point cloud:
        its spread).
    gains : callable or (q,) array_like, optional
        Instead of ``smooth`` / ``sharpen``: gains of the OFP basis functions, see
        :func:`o3d_ofp.core.filtering.spectral_filter` (e.g.
        :func:`smooth_gains(5) <o3d_ofp.core.filtering.smooth_gains>`).
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

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> noisy = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> xyz = np.asarray(noisy.vertices)
    >>> bumps = 1 + 0.02 * np.random.default_rng(0).standard_normal(len(xyz))
    >>> noisy.vertices = o3d.utility.Vector3dVector(xyz * bumps[:, None])
    >>> smooth = ofp.filter_geometry(noisy, smooth=0.05)
    >>> def roughness(mesh):
    ...     return np.linalg.norm(np.asarray(mesh.vertices), axis=1).std()
    >>> len(smooth.vertices), bool(roughness(smooth) < 0.7 * roughness(noisy))
    (182, True)
    """
    if gains is not None and (smooth is not None or sharpen is not None):
        raise ValueError("give gains alone, or smooth and/or sharpen (not both)")
    if gains is None and smooth is None and sharpen is None:
        raise ValueError("give smooth (a radius in [0, 0.25]), sharpen (in [0, 2]) or gains")
    if gains is None:
        smooth = check_amount(DEFAULT_SMOOTH if smooth is None else smooth, "smooth", MAX_SMOOTH)
        if sharpen is not None:
            sharpen = check_amount(sharpen, "sharpen", MAX_SHARPEN)
    check_bool(keep_volume, "keep_volume")
    check_choice(components, "components", COMPONENTS)
    geometry = read_if_path(geometry, "geometry")
    V, F = as_arrays(geometry, name="geometry")  # a (vertices, faces) tuple too
    if basis is not None:
        if basis.n_vertices != V.shape[0]:
            raise ValueError(f"basis has {basis.n_vertices} vertices but the geometry has "
                             f"{V.shape[0]}: it belongs to another shape")  # fmt: skip
        warn_other_shape(getattr(basis, "eig", basis), V, "basis", "the geometry")
    if gains is None:
        # The low-pass needs only the Laplacian (and the cleaning) of an eigenbasis.
        eig = basis if basis is not None else spectrum.eigenbasis(V, F, k=1, components=components)
        if sharpen is None:
            X = smooth_coordinates(eig, V, smooth=smooth, keep_volume=keep_volume)
        else:
            X = sharpen_coordinates(eig, V, sharpen=sharpen, smooth=smooth, keep_volume=keep_volume)
        return like_target(geometry, vertices=X)
    if basis is None:
        eig = spectrum.eigenbasis(V, F, k=k, components=components)
        basis = ofp_basis(eig, order=order, preset=preset, tol=tol)
    elif not isinstance(basis, OFPBasis):
        raise TypeError(f"gains need an OFPBasis as basis; got {type(basis).__name__}")
    return like_target(geometry, vertices=spectral_filter(basis, V, gains))
