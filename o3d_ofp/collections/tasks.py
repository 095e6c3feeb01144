"""The work done for one shape of a collection, on a Dask worker or in the calling process.

Every function here takes only picklable arguments (the shared source, one shape's spec, the
options) and returns a :class:`~o3d_ofp.collections.results.TargetResult`; an exception of the
shape (unreadable file, refused shape, failed solve) becomes a failed record instead of
stopping the run. Each target's job is planned and run by :mod:`o3d_ofp.workflows.plan`, as
for a single pair.
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
from ..core.basis import OFPBasis
from ..core.spectrum import EigenBasis
from ..core.wording import AdvisedError, Said
from ..workflows.cache import basis_cache_path, fetch_basis, fetch_eigenbasis
from ..workflows.dense import CoarseShape
from ..workflows.maps import Correspondence
from ..workflows.options import ESTIMATION_K, BasisOptions, DetailOptions, MatchOptions, required_k
from ..workflows.pipeline import carry
from ..workflows.plan import plan_pair, prepare
from .results import TargetResult

__all__ = [
    "BasisJob",
    "ShapeSpec",
    "SharedSource",
    "TransferJob",
    "basis_task",
    "failed",
    "transfer_task",
    "worker_name",
]

logger = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class TransferJob:
    """Options of a collection transfer (validated where the engine builds it).

    Attributes
    ----------
    kind : {"colors", "texture", "detail"}
        What is transferred: vertex colors (the source's, or its texture sampled at its
        vertices), the source's texture (or vertex colors) baked into each target's own UV
        layout (targets without UVs get vertex colors), or geometric detail.
    map : {"estimate", "identity"}
        How each target's map is made: estimated (descriptors, ZoomOut), or the identity
        (targets with the source's vertices, e.g. registrations of one template).
    bases : BasisOptions or None
        The OFP bases, when the caller set them (None: the task's defaults).
    detail : DetailOptions
        Detail transfer (kind "detail").
    components : str
        Connected-component policy of the eigenbases.
    strict : bool
        A suspect map fails the target (nothing written).
    signal : {"auto", "colors", "texture"}
        What the source's colors are (kinds "colors" and "texture"): its vertex colors, its
        texture sampled at its vertices, or (auto) the first of these it has.
    texture_size : int
        Side of the baked image (kind "texture").
    atlas : bool
        Kind "texture": a mesh target without UVs gets a new UV atlas to bake into.
    texture : str or None
        The source's texture image (absolute path), for a source read without its own.
    cache_dir : str or None
        Eigenbasis / basis cache folder.
    """

    kind: str = "colors"
    map: str = "estimate"
    bases: BasisOptions | None = None
    detail: DetailOptions = dataclasses.field(default_factory=DetailOptions)
    components: str = "auto"
    strict: bool = False
    signal: str = "auto"
    texture_size: int = 1024
    atlas: bool = False
    texture: str | None = None
    cache_dir: str | None = None

    @property
    def match(self) -> MatchOptions:
        """How each target's map is estimated."""
        return MatchOptions(components=self.components)

    def task(self, target: Any = None, *, mesh: bool = True) -> str:
        """Return the planner's task for a target (None: the source's side, any target)."""
        if self.kind == "detail":
            return "detail"
        bake = self.kind == "texture" and target is not None and not isinstance(target, tuple)
        if bake and (has_uvs(target) or (self.atlas and mesh)):
            return "texture"
        return "colors"


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
        Source eigenbasis, as the source's plan sizes it (the estimation's ~100, or the
        transfer's own on the dense path).
    basis : OFPBasis or None
        Source OFP basis (kinds "colors" and "texture").
    signal : (n1, 3) ndarray or None
        Source vertex colors (kinds "colors" and "texture").
    job : TransferJob
        The options.
    texture : MeshTexture, VertexColorSurface or None
        The source's UVs and images, or its vertex colors (kind "texture").
    coarse : CoarseShape or None
        The source's coarse copy and its eigenbasis, for a source on the dense path: reduced
        once, not per target.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray | None
    eig: EigenBasis
    basis: OFPBasis | None
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


def _identity(source: SharedSource, n2: int) -> Correspondence:
    """Return the identity map (``map="identity"``): the target has the source's vertices."""
    n1 = source.vertices.shape[0]
    if n1 != n2:
        raise AdvisedError(Said(
            "the identity map ({identity}) needs a target with the source's {n1} vertices; it "
            "has {n2}", {"n1": n1, "n2": n2}, "identity_size",
        ))  # fmt: skip
    return Correspondence(p2p_21=np.arange(n2), n_source=n1, method="identity")


#: Appended to a suspect map's fix in a collection, which takes no landmarks ({command} and
#: {function}: the command and the Python function of the collection's kind).
ALONE_WITH_LANDMARKS = (
    "a collection takes no landmarks: transfer this target alone (o3d-ofp {command} SOURCE "
    "TARGET --landmarks ..., or ofp.match(source, target, landmarks=...), then "
    "ofp.{function}(..., correspondence=...))"
)
#: Appended to a message whose fix is a partial match, which a collection does not make.
ALONE_PARTIAL = (
    "a collection makes no partial match: transfer this target alone (o3d-ofp {command} "
    "SOURCE TARGET --partial, or ofp.match(source, target, partial=True))"
)
#: The findings whose fix is a partial match (not the "likely causes" that name it among
#: others).
_PARTIAL_FIXES = ("looks_partial", "looks_partial_units", "cloud_part", "part_larger")


def _for_collections(message: str | Said, kind: str = "colors") -> str:
    """Return a library message's words, with the fix a collection cannot apply: run it alone.

    The fixes are read from the message's codes (a landmarks fix, a partial match), never from
    its words; ``kind`` names the collection's command and Python function.
    """
    command, function = ("detail", "transfer_detail") if kind == "detail" else (
        "transfer", "transfer_texture" if kind == "texture" else "transfer_colors"
    )  # fmt: skip
    if not isinstance(message, Said):
        return message
    text = message.text()
    if {"landmarks", "landmarks_check"} & set(message.fixes):
        text += f" ({ALONE_WITH_LANDMARKS.format(command=command, function=function)})"
    codes = {message.code} | {getattr(v, "code", "") for v in message.values.values()}
    if codes & set(_PARTIAL_FIXES):
        text += f" ({ALONE_PARTIAL.format(command=command)})"
    return text


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


_SILENCED = False


def _silence_warnings_on_this_worker() -> None:
    global _SILENCED
    if not _SILENCED:
        warnings.filterwarnings("ignore", category=OFPWarning)
        _SILENCED = True


def _transfer_task(source: SharedSource, spec: ShapeSpec) -> TargetResult:
    """Transfer the source's colors or detail onto one target; never raises for the target."""
    job = source.job
    t0 = time.perf_counter()
    n2, cached, coverage, suspect = 0, False, math.nan, None
    notes: tuple[str, ...] = ()
    made = job.kind
    try:
        target, V2, F2 = _read(spec)
        n2 = V2.shape[0]
        V1, F1 = source.vertices, source.faces
        given = _identity(source, n2) if job.map == "identity" else None
        task = job.task(target, mesh=spec.arrays is None and F2 is not None)
        plan = plan_pair(
            V1, F1, V2, F2, task=task, match=job.match, given=given, detail=job.detail,
            bases=None if task == "texture" else job.bases,  # (checked by the source's plan)
        )  # fmt: skip
        prepared = prepare(
            plan, V1, F1, V2, F2, match=job.match, given=given, eigenbases=(source.eig, None),
            bases=(source.basis, None), cache_dir=job.cache_dir, coarse_source=source.coarse,
        )  # fmt: skip
        corr, cached = prepared.correspondence, prepared.cached[1]
        if corr.quality is not None:
            coverage, suspect = corr.quality.coverage, corr.quality.suspect
            notes = tuple(_for_collections(n, job.kind) for n in corr.quality.notes)
        else:
            coverage, suspect = np.unique(corr.p2p_21).size / corr.n_source, False
        if suspect and job.strict:
            reasons = "; ".join(_for_collections(r, job.kind) for r in corr.quality.reasons)
            raise ValueError(f"suspect map (strict): {reasons}")
        values, result = None, None
        if task == "texture":
            assert source.texture is not None
            result = transfer_texture(
                source.texture, target, correspondence=corr, size=job.texture_size,
                atlas=job.atlas,
            )  # fmt: skip
        elif task == "colors":
            made = "colors"  # a target without UVs (and no atlas): its vertices get the colors
            values = np.clip(carry(source.signal, plan, prepared), 0.0, 1.0)
        else:
            result = transfer_detail(
                (V1, F1), target, correspondence=corr, mode=job.detail.mode,
                band=job.detail.band, amount=job.detail.amount, options=job.bases,
                bases=(prepared.eig_1, prepared.eig_2) if prepared.bases is None
                else prepared.bases,
            )  # fmt: skip
            values = geometry_to_arrays(result)[0]
        if spec.output is None and result is not None and values is None:
            raise ValueError("a baked texture needs an output folder (output_dir)")
        if spec.output is not None:
            if result is None or task == "detail":
                geometry = like_target(target, colors=values) if task == "colors" else result
                result = without_texture(geometry)
                if result is not geometry:
                    warn(logger, Said(
                        "{name}: its texture image is not written: the colors replace it on its "
                        "vertices ({texture_size} bakes them into its UV layout)",
                        {"name": spec.name}, "texture_dropped",
                    ))  # fmt: skip
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
        index=spec.index, name=spec.name, path=spec.path, status="ok", output=spec.output,
        seconds=time.perf_counter() - t0, coverage=float(coverage), suspect=bool(suspect),
        kind=made, n_vertices=n2, cached=cached, worker=worker_name(), notes=notes,
        values=values,
    )  # fmt: skip


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
