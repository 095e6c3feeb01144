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
import os
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from ..boundary.api import transfer_detail
from ..boundary.bake import has_uvs, transfer_texture
from ..boundary.convert import geometry_to_arrays, like_target
from ..boundary.io import read_geometry, write_geometry
from ..boundary.texture import MeshTexture, VertexColorSurface, without_texture
from ..core._validation import check_int
from ..core._warnings import OFPWarning, collected_warnings, warn
from ..core.basis import OFPBasis
from ..core.orthogonalize import resolve_tol
from ..core.spectrum import DEFAULT_K, EigenBasis
from ..core.texture import MAX_TEXTURE_SIZE
from ..core.wording import AdvisedError, OptionError, Said
from ..workflows.cache import basis_cache_path, fetch_basis, fetch_eigenbasis
from ..workflows.dense import CoarseShape
from ..workflows.maps import Correspondence
from ..workflows.options import (
    COMPONENTS,
    BasisOptions,
    DetailOptions,
    MatchOptions,
    check_bool,
    check_choice,
)
from ..workflows.pipeline import carry
from ..workflows.plan import Plan, Prepared, plan_pair, prepare
from .results import TargetResult

__all__ = ["BasisJob", "ShapeSpec", "SharedSource", "TransferJob", "basis_task", "failed",
           "transfer_task"]  # fmt: skip

logger = logging.getLogger(__name__)

#: What a collection transfers.
KINDS = ("colors", "texture", "detail")


@dataclasses.dataclass(frozen=True)
class TransferJob:
    """Options of a collection transfer, each checked here (as the options objects check theirs).

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
        The OFP bases, when the caller set them (None: the planner's defaults).
    detail : DetailOptions
        Detail transfer (kind "detail").
    components : {"auto", "largest", "error"}
        Connected-component policy of the eigenbases.
    strict : bool
        A suspect map fails the target (nothing written).
    shells : bool
        A doubtful estimated map is re-estimated by registering the shapes' smooth shells (see
        :class:`o3d_ofp.MatchOptions`).
    same_frame : bool
        The shapes are given in one frame: a shells registration keeps it where it cannot tell
        front from back (see :class:`o3d_ofp.MatchOptions`).
    signal : {"auto", "colors", "texture"}
        What the source's colors are (kinds "colors" and "texture"): its vertex colors, its
        texture sampled at its vertices, or (auto) the first of these it has.
    texture_size : int
        Side of the baked image (kind "texture").
    atlas : bool
        Kind "texture": a mesh target without UVs gets a new UV atlas to bake into.
    texture : str or None
        The source's texture image (made an absolute path), for a source read without its own.
    cache_dir : str or None
        Eigenbasis / basis cache folder.
    """

    kind: str = "colors"
    map: str = "estimate"
    bases: BasisOptions | None = None
    detail: DetailOptions = dataclasses.field(default_factory=DetailOptions)
    components: str = "auto"
    strict: bool = False
    shells: bool = True
    same_frame: bool = False
    signal: str = "auto"
    texture_size: int = 1024
    atlas: bool = False
    texture: str | None = None
    cache_dir: str | None = None
    #: How each target's map is estimated (made of ``components``, ``shells`` and
    #: ``same_frame``, which it checks).
    match: MatchOptions = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        check_choice(self.kind, "kind", KINDS)
        check_choice(self.map, "map", ("estimate", "identity"))
        match = MatchOptions(components=self.components, shells=self.shells,
                             same_frame=self.same_frame)  # fmt: skip
        object.__setattr__(self, "match", match)
        check_choice(self.signal, "signal", ("auto", "colors", "texture"))
        check_bool(self.strict, "strict")
        check_bool(self.atlas, "atlas")
        check_int(self.texture_size, name="texture_size", minimum=1, maximum=MAX_TEXTURE_SIZE)
        if self.kind == "texture" and self.signal == "colors":
            raise OptionError("signal", "'colors' does not apply to kind='texture' (a bake)")
        if self.texture is None:
            return
        if not isinstance(self.texture, (str, os.PathLike)):
            raise OptionError("texture", f"must be an image file path; got {self.texture!r}")
        if self.kind == "detail" or self.signal == "colors":
            raise OptionError("texture", "(the source's texture image) applies to its colors or "
                              "bake")  # fmt: skip
        object.__setattr__(self, "texture", os.path.abspath(os.fspath(self.texture)))
        if not os.path.isfile(self.texture):
            raise FileNotFoundError(f"texture {self.texture}: no such image file")

    def task(self, target: Any = None, *, mesh: bool = True) -> str:
        """Return the planner's task for a target (None: the source's side, any target)."""
        if self.kind == "detail":
            return "detail"
        bake = self.kind == "texture" and target is not None and not isinstance(target, tuple)
        return "texture" if bake and (has_uvs(target) or (self.atlas and mesh)) else "colors"


@dataclasses.dataclass(frozen=True)
class BasisJob:
    """Options of :func:`~o3d_ofp.collections.bases_many`, checked here."""

    cache_dir: str
    k: int = DEFAULT_K
    order: int = 2
    tol: float | None = None
    preset: str | None = "ours"
    components: str = "auto"
    eigenbasis_k: int | None = MatchOptions.zoomout_to

    def __post_init__(self) -> None:
        for name in ("k", "order", "eigenbasis_k"):
            if getattr(self, name) is not None:
                check_int(getattr(self, name), name=name, minimum=1)
        check_choice(self.components, "components", COMPONENTS)
        resolve_tol(self.tol, self.preset)


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
        Source eigenbasis, as the source's plan sizes it.
    basis : OFPBasis or None
        Source OFP basis (when the plan has one).
    signal : (n1, 3) ndarray or None
        Source vertex colors (kinds "colors" and "texture").
    job : TransferJob
        The options.
    texture : MeshTexture, VertexColorSurface or None
        The source's UVs and images, or its vertex colors (kind "texture").
    coarse : CoarseShape or None
        The source's coarse copy and its eigenbasis, for a source on the dense path.
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
        Where the result goes: written by the worker for a file, by the caller for a geometry
        (the worker returns the values; ``None``: nothing is written).
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


def failed(spec: ShapeSpec, exc: BaseException | str, *, kind: str, **found: Any) -> TargetResult:
    """Return the failed record of ``spec``: the exception's type and message, or ``exc``.

    An exception that carries a Said keeps it (a front end words it for its reader).
    """
    error: str | Said = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    if isinstance(getattr(exc, "said", None), Said):
        said = exc.said  # type: ignore[union-attr]
        error = Said("{kind}: {said}", {"kind": type(exc).__name__, "said": said})
    return TargetResult(spec.index, spec.name, spec.path, "failed", error=error, kind=kind, **found)


def _read(spec: ShapeSpec) -> tuple[Any, np.ndarray, np.ndarray | None]:
    """(geometry or (V, F) tuple, vertices, faces) of a shape."""
    if spec.path is not None:
        geometry = read_geometry(spec.path)
        return (geometry, *geometry_to_arrays(geometry))
    assert spec.arrays is not None
    return (spec.arrays, *spec.arrays)


#: Appended to a message whose fix is landmarks, which a collection does not take ({command}
#: and {function}: the command and the Python function of the collection's kind).
ALONE_WITH_LANDMARKS = ("a collection takes no landmarks: transfer this target alone (o3d-ofp "
                        "{command} SOURCE TARGET --landmarks ..., or ofp.match(source, target, "
                        "landmarks=...), then ofp.{function}(..., correspondence=...))")
#: Appended to a message whose fix is a partial match, which a collection does not make.
ALONE_PARTIAL = ("a collection makes no partial match: transfer this target alone (o3d-ofp "
                 "{command} SOURCE TARGET --partial, or ofp.match(source, target, partial=True))")
#: Appended to a message whose fix is a map of the caller's or a closest-point map: a
#: collection's maps are estimated or the identity.
ALONE_WITH_MAP = ("a collection's maps are estimated or the identity: transfer this target "
                  "alone (o3d-ofp {command} SOURCE TARGET --map FILE or --map closest, or "
                  "ofp.{function}(source, target, correspondence=...))")
#: The fixes of a message that need a map a collection does not take.
_MAP_FIXES = {"give_map", "closest", "coordinates_closest", "align"}
#: The findings whose fix is a partial match (not the "likely causes" that name it among
#: others).
_PARTIAL_FIXES = {"looks_partial", "looks_partial_units", "cloud_part", "part_larger"}


def _codes(message: Said) -> set[str]:
    """Return the codes of a message and of the messages in it."""
    inner = (_codes(v) for v in message.values.values() if isinstance(v, Said))
    return {message.code}.union(*inner)


def _for_collections(message: str | Said, kind: str = "colors") -> str | Said:
    """Return a library message with the fix a collection cannot apply: the target run alone.

    The fixes are read from the message's codes (landmarks, a partial match, a map of the
    caller's or of closest points), never from its words; ``kind`` names the collection's
    command and Python function. The message stays a Said (a front end words it for its
    reader).
    """
    if not isinstance(message, Said):
        return message
    command = "detail" if kind == "detail" else "transfer"
    function = f"transfer_{kind if kind in ('detail', 'texture') else 'colors'}"
    alone, fixes = [], set(message.fixes)
    if {"landmarks", "landmarks_check"} & fixes:
        alone.append(ALONE_WITH_LANDMARKS.format(command=command, function=function))
    if _codes(message) & _PARTIAL_FIXES:
        alone.append(ALONE_PARTIAL.format(command=command))
    if _MAP_FIXES & fixes:
        alone.append(ALONE_WITH_MAP.format(command=command, function=function))
    if not alone:
        return message
    extra = "".join(f" ({a})" for a in alone).replace("{", "{{").replace("}", "}}")
    return Said("{message}" + extra, {"message": message}, message.code)


def transfer_task(source: SharedSource, spec: ShapeSpec) -> TargetResult:
    """Transfer the source onto one target; what the library said of it is kept in its record.

    The warnings issued in this thread are collected
    (:func:`~o3d_ofp.core._warnings.collected_warnings`: thread-safe, whatever the logging
    levels). On a Dask worker the OFPWarnings themselves are silenced (the worker process
    would print them away from the run's log); the caller logs each record's warnings with
    the target's name.
    """
    if worker_name() != "local":
        warnings.filterwarnings("ignore", category=OFPWarning)
    with collected_warnings() as said:
        result = _recorded(spec, source.job.kind, lambda found: _transfer_task(source, spec, found))
    worded = (_for_collections(m, source.job.kind) for m in said)
    messages = tuple({str(m): m for m in worded}.values())  # each said once
    return dataclasses.replace(result, warnings=messages) if messages else result


def _recorded(spec: ShapeSpec, kind: str, work: Callable[[dict[str, Any]], dict[str, Any]]
              ) -> TargetResult:  # fmt: skip
    """Run ``work(found)`` for one shape and return its record; never raises for the shape.

    ``work`` puts in ``found`` what it learns of the shape (kept in a failed record) and
    returns the other fields of its record (status "ok" and ``kind`` unless it gives them).
    """
    t0, found = time.perf_counter(), {}
    try:
        fields = {"status": "ok", "kind": kind, **work(found), **found}
    except Exception as exc:  # a shape's failure is its record, never the run's
        logger.debug("%s: failed: %s: %s", spec.name, type(exc).__name__, exc)  # the caller logs it
        seconds = time.perf_counter() - t0
        return failed(spec, exc, kind=kind, seconds=seconds, worker=worker_name(), **found)
    return TargetResult(spec.index, spec.name, spec.path, seconds=time.perf_counter() - t0,
                        worker=worker_name(), **fields)  # fmt: skip


def _transfer_task(source: SharedSource, spec: ShapeSpec, found: dict[str, Any]) -> dict[str, Any]:
    """Map the source onto one target and transfer; the fields of its record."""
    job = source.job
    target, V2, F2 = _read(spec)
    found["n_vertices"] = V2.shape[0]
    task = job.task(target, mesh=spec.arrays is None and F2 is not None)
    plan, prepared = _prepared(source, V2, F2, task)
    corr = prepared.correspondence
    found.update(cached=prepared.cached[1], **_verdict(corr, job.kind))
    if job.strict and found["suspect"]:
        reasons = [_for_collections(r, job.kind) for r in corr.quality.reasons]
        template = "; ".join(f"{{r{i}}}" for i in range(len(reasons)))
        raise AdvisedError(Said("suspect map (strict): " + template,
                                {f"r{i}": r for i, r in enumerate(reasons)}, "strict"))
    values = _transferred(source, spec, target, plan, prepared)
    # a geometry's output is written by the caller, from the values
    return {"output": spec.output, "kind": task, "values": values}


def _prepared(source: SharedSource, V2: np.ndarray, F2: np.ndarray | None,
              task: str) -> tuple[Plan, Prepared]:  # fmt: skip
    """Plan the target's job and run the plan with the source's shared bases."""
    job, V1, F1 = source.job, source.vertices, source.faces
    given = None
    if job.map == "identity":
        n1, n2 = V1.shape[0], V2.shape[0]
        if n1 != n2:
            raise AdvisedError(Said(
                "the identity map ({identity}) needs a target with the source's {n1} vertices; "
                "it has {n2}", {"n1": n1, "n2": n2}, "identity_size",
            ))  # fmt: skip
        given = Correspondence(p2p_21=np.arange(n2), n_source=n1, method="identity")
    plan = plan_pair(
        V1, F1, V2, F2, task=task, match=job.match, given=given, detail=job.detail,
        bases=None if task == "texture" else job.bases, names=(source.name, "the target"),
    )  # fmt: skip
    prepared = prepare(
        plan, V1, F1, V2, F2, match=job.match, given=given, eigenbases=(source.eig, None),
        bases=(source.basis, None), cache_dir=job.cache_dir, coarse_source=source.coarse,
    )  # fmt: skip
    return plan, prepared


def _verdict(corr: Correspondence, kind: str) -> dict[str, Any]:
    """Return the map's coverage, suspect flag and notes (in a collection's words)."""
    quality = corr.quality
    if quality is None:  # a given map: judged by nothing but its coverage
        return {"coverage": np.unique(corr.p2p_21).size / corr.n_source, "suspect": False}
    notes = tuple(_for_collections(n, kind) for n in quality.notes)
    return {"coverage": float(quality.coverage), "suspect": bool(quality.suspect), "notes": notes}


def _transferred(source: SharedSource, spec: ShapeSpec, target: Any, plan: Plan,
                 prepared: Prepared) -> np.ndarray | None:  # fmt: skip
    """Transfer onto the target and write it (a file's); else return the values."""
    job, corr = source.job, prepared.correspondence
    keep = spec.output is None or spec.arrays is not None  # a geometry's: written by the caller
    if plan.task == "texture":  # (a texture run has an output folder)
        assert source.texture is not None
        result = transfer_texture(source.texture, target, correspondence=corr,
                                  size=job.texture_size, atlas=job.atlas)  # fmt: skip
    elif plan.task == "detail":
        result = transfer_detail(
            (source.vertices, source.faces), target, correspondence=corr, mode=job.detail.mode,
            band=job.detail.band, amount=job.detail.amount, options=job.bases,
            bases=prepared.bases or (prepared.eig_1, prepared.eig_2),
        )  # fmt: skip
    else:
        values = np.clip(carry(source.signal, plan, prepared), 0.0, 1.0)
        if keep:
            return values
        colored = like_target(target, colors=values)
        result = without_texture(colored)
        if result is not colored:
            warn(logger, Said(
                "{name}: its texture image is not written: the colors replace it on its "
                "vertices ({texture_size} bakes them into its UV layout)",
                {"name": spec.name}, "texture_dropped",
            ))  # fmt: skip
    if keep:
        return geometry_to_arrays(result)[0]
    write_geometry(spec.output, result)
    return None


def basis_task(job: BasisJob, spec: ShapeSpec) -> TargetResult:
    """Compute (or find) one shape's cached eigenbasis and OFP basis; never raises for it.

    ``output`` of the record is the basis' cache file; ``skipped`` when every entry was
    already cached.
    """
    return _recorded(spec, "basis", lambda found: _basis_task(job, spec, found))


def _basis_task(job: BasisJob, spec: ShapeSpec, found: dict[str, Any]) -> dict[str, Any]:
    """Fetch one shape's bases into the cache; the fields of its record."""
    basis = {"k": job.k, "order": job.order, "tol": job.tol, "preset": job.preset}
    _, V, F = _read(spec)
    found["n_vertices"] = V.shape[0]
    eig, cached = None, True
    if job.eigenbasis_k is not None:  # the eigenbasis a map estimation plans for this shape
        k = job.eigenbasis_k
        match = MatchOptions(zoomout_to=k, k_fit=min(k, MatchOptions.k_fit),
                             components=job.components)  # fmt: skip
        plan = plan_pair(V, F, None, None, task="map", match=match)
        if plan.eig_k[0]:  # (none on the dense path)
            eig, cached = fetch_eigenbasis(
                V, F, k=plan.eig_k[0], clamp_k=plan.clamp[0], cache_dir=job.cache_dir,
                components=job.components,
            )  # fmt: skip
        if eig is not None and eig.k < job.k:
            eig = None  # smaller than the basis needs: fetch_basis solves again
    cached &= fetch_basis(V, F, **basis, cache_dir=job.cache_dir, eig=eig,
                          components=job.components)[1]  # fmt: skip
    output = basis_cache_path(V, F, **basis, cache_dir=job.cache_dir, components=job.components)
    return {"status": "skipped" if cached else "ok", "output": output, "cached": cached}
