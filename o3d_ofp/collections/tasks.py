"""The work done for one shape of a collection, on a Dask worker or in the calling process.

Every function here takes only picklable arguments (the shared source, one shape's spec, the
options) and returns a :class:`~o3d_ofp.collections.results.TargetResult`; an exception of the
shape (unreadable file, refused shape, failed solve) becomes a failed record instead of
stopping the run.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
import warnings
from typing import Any

import numpy as np

from ..boundary.api import transfer_detail
from ..boundary.bake import has_uvs, transfer_texture
from ..boundary.convert import geometry_to_arrays, like_target
from ..boundary.io import read_geometry, write_geometry
from ..boundary.texture import MeshTexture, VertexColorSurface, without_texture
from ..core._warnings import OFPWarning, collected_warnings, warn
from ..core.basis import OFPBasis, ofp_basis
from ..core.spectrum import EigenBasis, eigenbasis
from ..workflows.cache import basis_cache_path, fetch_basis, fetch_eigenbasis
from ..workflows.dense import CoarseShape
from ..workflows.detail import DETAIL_BAND, ROTATION_K
from ..workflows.matching import (
    ESTIMATION_K,
    Correspondence,
    match_arrays,
    match_eigenbases,
    required_k,
    uses_dense_path,
)
from ..workflows.pipeline import transfer_function
from .results import TargetResult

__all__ = [
    "BasisJob",
    "ShapeSpec",
    "SharedSource",
    "TransferJob",
    "basis_task",
    "failed",
    "shape_bases",
    "transfer_task",
    "worker_name",
]

logger = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class TransferJob:
    """Options of a collection transfer (validated by the engine).

    Attributes
    ----------
    kind : {"colors", "texture", "detail"}
        What is transferred: vertex colors (the source's, or its texture sampled at its
        vertices), the source's texture (or vertex colors) baked into each target's own UV
        layout (targets without UVs get vertex colors), or geometric detail.
    map : {"estimate", "identity"}
        How each target's map is made: estimated (descriptors, ZoomOut), or the identity
        (targets with the source's vertices, e.g. registrations of one template).
    k1, k2, order, tol, preset
        The OFP bases of source and target (see :func:`o3d_ofp.transfer_function`).
    mode, band, amount
        Detail transfer (see :func:`o3d_ofp.transfer_detail`).
    signal : {"auto", "colors", "texture"}
        What the source's colors are (kinds "colors" and "texture"): its vertex colors, its
        texture sampled at its vertices, or (auto) the first of these it has.
    texture_size : int
        Side of the baked image (kind "texture").
    atlas : bool
        Kind "texture": a mesh target without UVs gets a new UV atlas to bake into.
    texture : str or None
        The source's texture image (absolute path), for a source read without its own.
    components : str
        Connected-component policy of the eigenbases.
    strict : bool
        A suspect map fails the target (nothing written).
    cache_dir : str or None
        Eigenbasis / basis cache folder.
    """

    kind: str = "colors"
    map: str = "estimate"
    k1: int = 29
    k2: int = 39
    order: int = 2
    tol: float | None = None
    preset: str | None = "ours"
    mode: str = "add"
    band: int = DETAIL_BAND
    amount: float = 1.0
    components: str = "auto"
    strict: bool = False
    signal: str = "auto"
    texture_size: int = 1024
    atlas: bool = False
    texture: str | None = None
    cache_dir: str | None = None

    def eig_k(self, n_vertices: int, side: int, *, dense: bool = False) -> tuple[int, bool]:
        """(k, clamp_k) of a shape's eigenbasis: ~100 for map estimation, else k1 / k2.

        ``dense``: the map of this shape is estimated on coarse copies (the dense path), so
        its own eigenbasis serves the transfer only.
        """
        k = self.k1 if side == 1 else self.k2
        if self.kind == "detail" and self.mode != "coordinates":
            k = max(k, self.band, ROTATION_K)  # the detail band and the local frames
        if self.map == "estimate" and not dense:
            estimation = required_k(n_vertices, ESTIMATION_K)
            if k <= estimation:  # the estimation's size holds the transfer's too
                return estimation, True
        # Exactly k (more than the estimation needs, e.g. --k1 150): a shape too small for
        # it is refused by the eigensolver, as for a pair (it was capped at 99 silently).
        return k, False


@dataclasses.dataclass(frozen=True)
class BasisJob:
    """Options of :func:`~o3d_ofp.collections.bases_many` (validated by the engine)."""

    cache_dir: str
    k: int = 29
    order: int = 2
    tol: float | None = None
    preset: str | None = "ours"
    components: str = "auto"
    eigenbasis_k: int | None = ESTIMATION_K


@dataclasses.dataclass(frozen=True, eq=False)
class SharedSource:
    """The source, computed once in the caller and shared with every task.

    Attributes
    ----------
    name : str
        For messages.
    vertices : (n1, 3) ndarray of float64
        Source positions.
    faces : (m1, 3) ndarray of int64 or None
        Source triangles.
    eig : EigenBasis
        Source eigenbasis (k = 99 for map estimation; k1, or the detail band, for a source on
        the dense path, whose maps are estimated on coarse copies).
    basis : OFPBasis
        Source OFP basis (k1 eigenfunctions).
    signal : (n1, 3) ndarray or None
        Source vertex colors (kinds "colors" and "texture").
    job : TransferJob
        The options.
    texture : MeshTexture, VertexColorSurface or None
        The source's UVs and images, or its vertex colors (kind "texture").
    coarse : CoarseShape or None
        The source's coarse copy and its eigenbasis, for a source on the dense path (its maps
        to mesh targets are estimated on coarse copies): reduced once, not per target.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray | None
    eig: EigenBasis
    basis: OFPBasis
    signal: np.ndarray | None
    job: TransferJob
    texture: MeshTexture | VertexColorSurface | None = None
    coarse: CoarseShape | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class ShapeSpec:
    """One shape to process: a file, or the arrays of a geometry given in memory.

    Attributes
    ----------
    index : int
        Position in the run.
    name : str
        Output file name (and the name in messages).
    path : str or None
        Input file (read on the worker).
    arrays : ((n, 3) ndarray, (m, 3) ndarray or None) or None
        Vertices and faces of a geometry given in memory.
    output : str or None
        Where the worker writes the result (``None``: return the values instead).
    """

    index: int
    name: str
    path: str | None
    arrays: tuple[np.ndarray, np.ndarray | None] | None = None
    output: str | None = None


def worker_name() -> str:
    """Address of the Dask worker running this task, or ``"local"``."""
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return "local"


def failed(
    spec: ShapeSpec, error: str, *, kind: str, seconds: float = 0.0, **extra: Any
) -> TargetResult:
    """Return a failed record for ``spec`` with the message ``error``."""
    return TargetResult(
        index=spec.index,
        name=spec.name,
        path=spec.path,
        status="failed",
        seconds=seconds,
        error=error,
        kind=kind,
        **extra,
    )


def _read(spec: ShapeSpec) -> tuple[Any, np.ndarray, np.ndarray | None]:
    """(geometry or (V, F) tuple, vertices, faces) of a shape."""
    if spec.path is not None:
        geometry = read_geometry(spec.path)
        V, F = geometry_to_arrays(geometry)
        return geometry, V, F
    assert spec.arrays is not None
    V, F = spec.arrays
    return (V, F), V, F


def shape_bases(
    V: np.ndarray,
    F: np.ndarray | None,
    job: TransferJob,
    side: int,
    *,
    dense: bool = False,
) -> tuple[EigenBasis, OFPBasis, bool]:
    """Eigenbasis and OFP basis of one side of a transfer, from the cache when there is one.

    Parameters
    ----------
    V : (n, 3) ndarray of float64
        Vertices.
    F : (m, 3) ndarray of int64 or None
        Triangles (``None``: a point cloud).
    job : TransferJob
        The options.
    side : {1, 2}
        Source (k1) or target (k2).
    dense : bool, default False
        The shape's map is estimated on the dense path (no ~100-eigenfunction basis needed).

    Returns
    -------
    eig : EigenBasis
        ~100 eigenfunctions for map estimation, else ``k1`` / ``k2``.
    basis : OFPBasis
        The OFP basis on ``k1`` / ``k2`` of them.
    cached : bool
        Whether the eigenbasis came from the cache.
    """
    k_eig, clamp = job.eig_k(V.shape[0], side, dense=dense)
    k_basis = job.k1 if side == 1 else job.k2
    if not clamp and k_eig >= V.shape[0]:  # before any work: the shape cannot hold them
        flag, name = ("k1", "source") if side == 1 else ("k2", "target")
        band = f", band = {job.band}" if job.kind == "detail" and k_eig > k_basis else ""
        raise ValueError(
            f"{flag} = {k_basis}{band}: the {name} has {V.shape[0]} vertices, too few for "
            f"{k_eig} eigenfunctions; give a smaller {flag} (--{flag})"
        )
    if job.cache_dir is not None:
        eig, cached = fetch_eigenbasis(
            V, F, k=k_eig, clamp_k=clamp, cache_dir=job.cache_dir, components=job.components
        )
        _check_basis_size(eig, k_basis, side)
        B, _ = fetch_basis(
            V, F, k=k_basis, order=job.order, tol=job.tol, preset=job.preset,
            cache_dir=job.cache_dir, eig=eig, components=job.components,
        )  # fmt: skip
        return eig, B, cached
    eig = eigenbasis(V, F, k=k_eig, clamp_k=clamp, components=job.components)
    _check_basis_size(eig, k_basis, side)
    B = ofp_basis(eig, order=job.order, tol=job.tol, preset=job.preset, k=k_basis)
    return eig, B, False


def _check_basis_size(eig: EigenBasis, k_basis: int, side: int) -> None:
    """Refuse a basis larger than the shape's eigenbasis (a shape too small for k1 / k2)."""
    if k_basis > eig.k:
        flag, name = ("k1", "source") if side == 1 else ("k2", "target")
        raise ValueError(
            f"{flag} = {k_basis}: the {name} has only {eig.k} non-constant eigenfunctions "
            f"({eig.n_vertices} vertices); give a smaller {flag}"
        )


def _dense_pair(source: SharedSource, V2: np.ndarray, F2: np.ndarray | None) -> bool:
    """Whether this target's map is estimated on the dense path (coarse copies)."""
    meshes = source.faces is not None and F2 is not None
    n1 = source.vertices.shape[0]
    return source.job.map == "estimate" and uses_dense_path(n1, V2.shape[0], meshes)


def _correspondence(
    source: SharedSource, eig_2: EigenBasis, V2: np.ndarray, F2: np.ndarray | None
) -> Correspondence:
    job = source.job
    if _dense_pair(source, V2, F2):  # the target's coarse basis is made here
        return match_arrays(
            source.vertices,
            source.faces,
            V2,
            F2,
            components=job.components,
            coarse_source=source.coarse,
        )
    if job.map == "estimate":
        eig_1 = source.eig
        need = required_k(eig_1.n_vertices, ESTIMATION_K)
        if eig_1.k < need:  # a large source (dense path) onto a small or point-cloud target
            logger.info("source eigenbasis of %d functions for this target's estimation", need)
            eig_1 = eigenbasis(
                source.vertices, source.faces, k=need, clamp_k=True, components=job.components
            )
        return match_eigenbases(eig_1, eig_2)
    n1, n2 = source.eig.n_vertices, eig_2.n_vertices
    if n1 != n2:
        raise ValueError(
            f"the identity map (map='identity' / --map identity) needs a target with the "
            f"source's {n1} vertices; it has {n2}"
        )
    return Correspondence(p2p_21=np.arange(n2), n_source=n1, method="identity")


#: Appended to a suspect map's fix in a collection, which takes no landmarks ({command} and
#: {function}: the command and the Python function of the collection's kind).
ALONE_WITH_LANDMARKS = (
    "a collection takes no landmarks: transfer this target alone (o3d-ofp {command} SOURCE "
    "TARGET --landmarks ..., or ofp.{function}(..., landmarks=...))"
)


def transfer_task(source: SharedSource, spec: ShapeSpec) -> TargetResult:
    """Run :func:`_transfer_task`; what the library said of the target is kept in its record.

    The warnings (a suspect map with its reasons and fix, ...) issued in this thread are
    collected (:func:`~o3d_ofp.core._warnings.collected_warnings`: thread-safe, whatever the
    logging levels, e.g. ``-q``). On a Dask worker the OFPWarnings themselves are silenced:
    the process would print them away from the run's log and summary; the caller logs each
    record's warnings with the target's name.
    """
    if worker_name() != "local":
        _silence_warnings_on_this_worker()
    with collected_warnings() as said:
        result = _transfer_task(source, spec)
    messages = tuple(dict.fromkeys(_for_collections(m, source.job.kind) for m in said))
    return dataclasses.replace(result, warnings=messages) if messages else result


_SILENCED = False


def _silence_warnings_on_this_worker() -> None:
    global _SILENCED
    if not _SILENCED:
        warnings.filterwarnings("ignore", category=OFPWarning)
        _SILENCED = True


#: Appended to a message whose fix is a partial match, which a collection does not make.
ALONE_PARTIAL = (
    "a collection makes no partial match: transfer this target alone (o3d-ofp {command} "
    "SOURCE TARGET --partial, or ofp.match(source, target, partial=True))"
)


def _for_collections(message: str, kind: str = "colors") -> str:
    """Add to a library message the fix a collection cannot apply: the target run alone.

    ``kind``: the collection's (its command and Python function are named: a trial's detail
    run was told to re-run the target with ``o3d-ofp transfer``).
    """
    command, function = ("detail", "transfer_detail") if kind == "detail" else (
        "transfer", "transfer_texture" if kind == "texture" else "transfer_colors"
    )  # fmt: skip
    if "landmarks" in message:
        alone = ALONE_WITH_LANDMARKS.format(command=command, function=function)
        message = f"{message} ({alone})"
    # The fixes that use it (a part, a part in other units, a cloud that may be a part); not
    # the "likely causes" line, which names it among others.
    if any(f in message for f in ("fix: partial=True", "then partial=True", "with partial=True")):
        message = f"{message} ({ALONE_PARTIAL.format(command=command)})"
    return message


def _transfer_task(source: SharedSource, spec: ShapeSpec) -> TargetResult:
    """Transfer the source's colors or detail onto one target; never raises for the target.

    Parameters
    ----------
    source : SharedSource
        The source with its bases (shared by every task).
    spec : ShapeSpec
        The target.

    Returns
    -------
    TargetResult
        ``ok`` with the output written (or the values kept), or ``failed`` with the message.
    """
    job = source.job
    t0 = time.perf_counter()
    n2, cached, coverage, suspect = 0, False, math.nan, None
    notes: tuple[str, ...] = ()
    made = job.kind
    try:
        target, V2, F2 = _read(spec)
        n2 = V2.shape[0]
        eig_2, B2, cached = shape_bases(V2, F2, job, 2, dense=_dense_pair(source, V2, F2))
        corr = _correspondence(source, eig_2, V2, F2)
        if corr.quality is not None:
            coverage, suspect = corr.quality.coverage, corr.quality.suspect
            notes = tuple(_for_collections(n, job.kind) for n in corr.quality.notes)
        else:
            coverage, suspect = np.unique(corr.p2p_21).size / corr.n_source, False
        if suspect and job.strict:
            reasons = "; ".join(corr.quality.reasons)
            raise ValueError(f"suspect map (strict): {_for_collections(reasons, job.kind)}")
        bases = (source.basis, B2)
        if (
            job.kind == "texture"
            and not isinstance(target, tuple)
            and (has_uvs(target) or (job.atlas and spec.arrays is None and F2 is not None))
        ):
            assert source.texture is not None
            result = transfer_texture(
                source.texture, target, correspondence=corr, size=job.texture_size,
                atlas=job.atlas,
            )  # fmt: skip
            values = None
        elif job.kind in ("colors", "texture"):
            made = "colors"  # a target without UVs (and no atlas): its vertices get the colors
            g = transfer_function(
                source.signal, source.eig, eig_2, correspondence=corr, bases=bases
            )
            values, result = np.clip(g, 0.0, 1.0), None
        else:
            result = transfer_detail(
                (source.vertices, source.faces), target, mode=job.mode, band=job.band,
                amount=job.amount, k1=job.k1, k2=job.k2, order=job.order, tol=job.tol,
                preset=None if job.tol is not None else job.preset, correspondence=corr,
                eigenbases=(source.eig, eig_2), bases=bases,
            )  # fmt: skip
            values = geometry_to_arrays(result)[0]
        if spec.output is None and result is not None and values is None:
            raise ValueError("a baked texture needs an output folder (output_dir)")
        if spec.output is not None:
            if result is None:
                colored = like_target(target, colors=values)
                result = without_texture(colored)
                if result is not colored:
                    warn(
                        logger,
                        f"{spec.name}: its texture image is not written: the colors replace "
                        "it on its vertices (kind='texture' / --texture-size N bakes them into "
                        "its UV layout)",
                    )
            write_geometry(spec.output, result)
            values = None
    except Exception as exc:  # a target's failure is its record, never the run's
        logger.debug("%s: failed: %s: %s", spec.name, type(exc).__name__, exc)  # the caller logs it
        return failed(
            spec, f"{type(exc).__name__}: {exc}", kind=job.kind,
            seconds=time.perf_counter() - t0, n_vertices=n2, cached=cached, worker=worker_name(),
            notes=notes,
        )  # fmt: skip
    return TargetResult(
        index=spec.index,
        name=spec.name,
        path=spec.path,
        status="ok",
        output=spec.output,
        seconds=time.perf_counter() - t0,
        coverage=float(coverage),
        suspect=bool(suspect),
        kind=made,
        n_vertices=n2,
        cached=cached,
        worker=worker_name(),
        notes=notes,
        values=values,
    )


def basis_task(job: BasisJob, spec: ShapeSpec) -> TargetResult:
    """Compute (or find) one shape's cached eigenbasis and OFP basis; never raises for it.

    Parameters
    ----------
    job : BasisJob
        The options and the cache folder.
    spec : ShapeSpec
        The shape.

    Returns
    -------
    TargetResult
        ``output`` is the basis' cache file; ``skipped`` when every entry was already cached.
    """
    t0 = time.perf_counter()
    n, cached = 0, False
    try:
        _, V, F = _read(spec)
        n = V.shape[0]
        eig = None
        cached = True
        if job.eigenbasis_k is not None:
            eig, cached = fetch_eigenbasis(
                V, F, k=required_k(n, job.eigenbasis_k), clamp_k=True, cache_dir=job.cache_dir,
                components=job.components,
            )  # fmt: skip
            if eig.k < job.k:
                eig = None  # a smaller eigenbasis than the basis needs: fetch_basis solves again
        _, basis_cached = fetch_basis(
            V, F, k=job.k, order=job.order, tol=job.tol, preset=job.preset,
            cache_dir=job.cache_dir, eig=eig, components=job.components,
        )  # fmt: skip
        cached = cached and basis_cached
        output = basis_cache_path(
            V, F, k=job.k, order=job.order, tol=job.tol, preset=job.preset,
            cache_dir=job.cache_dir, components=job.components,
        )  # fmt: skip
    except Exception as exc:  # a shape's failure is its record, never the run's
        logger.debug("%s: failed: %s: %s", spec.name, type(exc).__name__, exc)  # the caller logs it
        return failed(
            spec, f"{type(exc).__name__}: {exc}", kind="basis",
            seconds=time.perf_counter() - t0, n_vertices=n, worker=worker_name(),
        )  # fmt: skip
    return TargetResult(
        index=spec.index,
        name=spec.name,
        path=spec.path,
        status="skipped" if cached else "ok",
        output=output,
        seconds=time.perf_counter() - t0,
        kind="basis",
        n_vertices=n,
        cached=cached,
        worker=worker_name(),
    )
