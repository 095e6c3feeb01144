"""The planner: what a job between two shapes computes, decided once, then run.

:func:`plan_pair` takes the two shapes, what is asked (a map, colors, a texture bake, detail)
and the validated options, and decides everything that ties the steps together: how the map
is made (given, closest points, a full or a partial estimate), whether it is estimated on
coarse copies (the dense path), how many eigenfunctions each shape needs, which OFP bases and
with which threshold, and whether values are pulled back through the map or carried by the
bases. :func:`prepare` runs the plan: eigenbases (computed side by side, cached, or given), the
map, the bases. The geometry-level functions, the command line and the collections all plan
with :func:`plan_pair` and run :func:`prepare`; none decides these things itself.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..core._memory import available_memory, basis_job_bytes, format_bytes
from ..core._threads import PARALLEL_ROWS
from ..core._warnings import warn
from ..core.basis import OFPBasis, ofp_basis
from ..core.orthogonalize import PRESETS
from ..core.spectrum import EigenBasis, eigenbasis
from ..core.wording import AdvisedError, OptionError, Said
from .cache import fetch_basis, fetch_eigenbasis
from .dense import COARSE_VERTICES, DENSE_VERTICES, CoarseShape
from .eigenbases import check_shapes, eigenbasis_bytes, run_per_shape, said_of
from .estimate import coarse_copies, estimate, estimate_dense, strategy_of
from .maps import Correspondence, given_map_collapse, same_shape, warn_other_shape
from .options import BasisOptions, DetailOptions, MatchOptions, check_choice
from .partial import check_partial_areas, refuse_clouds

__all__ = ["TASKS", "Plan", "Prepared", "plan_pair", "prepare", "prepare_source"]

logger = logging.getLogger(__name__)

#: What a job asks for: the map only, colors (or any signal) on the target's vertices, the
#: source's texture baked into the target's UVs, or the source's geometric detail.
TASKS = ("map", "colors", "texture", "detail")


@dataclasses.dataclass(frozen=True)
class Plan:
    """What a job between two shapes computes (made by :func:`plan_pair`, run by :func:`prepare`).

    Attributes
    ----------
    task : {"map", "colors", "texture", "detail"}
        What is asked.
    estimator : {"given", "closest", "full", "partial"}
        How the map is made: given by the caller, closest points (made at the Open3D
        boundary), or estimated for whole shapes or for a part.
    dense : bool
        The map is estimated on coarse copies (either mesh above
        :data:`~o3d_ofp.workflows.dense.DENSE_VERTICES` vertices): no full-resolution eigenpair
        serves the estimation.
    eig_k : (int, int)
        Non-constant eigenfunctions computed on each shape at full resolution (0: none).
    clamp : (bool, bool)
        Whether that count is the estimation's, capped by the shape's vertex count.
    basis_k : (int, int) or None
        Eigenfunctions multiplied in each OFP basis; None: no OFP basis.
    order : int
        Product order of the bases.
    tol : float
        Their drop threshold.
    matrix : {"p2p", "analytic"}
        How the transfer matrix between the bases is computed.
    exact : bool
        Values are pulled back through the map with no OFP basis.
    coarse_bases : (bool, bool)
        Whether each side's OFP basis is built on the shape's coarse copy (task "colors",
        a mesh above :data:`~o3d_ofp.workflows.dense.DENSE_VERTICES` vertices, no basis or
        eigenbasis given for it): the source's values are averaged over its cells, the
        target's result interpolated along its surface
        (:class:`~o3d_ofp.workflows.dense.CoarseShape`'s ``restriction`` and
        ``prolongation``), and no full-resolution eigenpair is computed for it. Through the
        true map of FAUST 093 -> 087 subdivided, the colors come out 5.34 % (110k vertices)
        and 5.57 % (440k) from the truth, against 5.39 % at 6.9k with full-resolution bases
        (relative L2; ``python scripts/bench_match.py --levels 0 1 2 3``, the bracketed
        colors error).
    operators : (bool, bool)
        Whether a side's full-resolution eigenbasis (``eig_k`` 1) serves only its operators:
        the calibrated detail (no ``band``, no OFP basis) where no estimation reads it.
    """

    task: str
    estimator: str
    dense: bool
    eig_k: tuple[int, int]
    clamp: tuple[bool, bool]
    basis_k: tuple[int, int] | None
    order: int
    tol: float
    matrix: str
    exact: bool
    coarse_bases: tuple[bool, bool] = (False, False)
    operators: tuple[bool, bool] = (False, False)

    @property
    def estimated(self) -> bool:
        """Whether the map is estimated spectrally here (full or partial)."""
        return self.estimator in ("full", "partial")


def plan_pair(
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray | None,
    F2: np.ndarray | None,
    *,
    task: str,
    match: MatchOptions | None = None,
    bases: BasisOptions | None = None,
    detail: DetailOptions | None = None,
    given: Correspondence | None = None,
    given_bases: Sequence[OFPBasis | None] = (None, None),
    eigenbases: Sequence[EigenBasis | None] = (None, None),
    via_basis: bool | None = None,
    names: tuple[str, str] = ("the source", "the target"),
) -> Plan:
    """Decide what a job between two shapes computes (the one function that does).

    Parameters
    ----------
    V1, F1 : (n1, 3) ndarray, (m1, 3) ndarray or None
        The source (faces None: a point cloud).
    V2, F2 : (n2, 3) ndarray or None, (m2, 3) ndarray or None
        The target; ``V2`` None: any target (a collection's source, planned alone: it takes
        the dense path when it is above the threshold itself).
    task : {"map", "colors", "texture", "detail"}
        What is asked.
    match : MatchOptions, optional
        How a map not given is made (default ``MatchOptions()``).
    bases : BasisOptions, optional
        The OFP bases of the task, when it has them (default ``BasisOptions()``); given with a
        task that builds none (an exact pull-back, a bake, detail in its local frames), refused.
    detail : DetailOptions, optional
        The detail transfer (task "detail"; default ``DetailOptions()``).
    given : Correspondence, optional
        A map the caller brings (then ``match`` is not used: a partial match or landmarks are
        refused).
    given_bases : (OFPBasis or None, OFPBasis or None)
        OFP bases the caller has: their sizes are the plan's on their side.
    eigenbases : (EigenBasis or None, EigenBasis or None)
        Eigenbases the caller has: with both, a map is estimated from them at full resolution
        (never on coarse copies, whatever the sizes).
    via_basis : bool, optional
        Task "colors": carry the values through the OFP bases (True) or pull them back through
        the map (False); default: pulled back through a closest-point map, carried otherwise.
    names : (str, str)
        How messages name the two shapes.

    Returns
    -------
    Plan

    Raises
    ------
    OptionError, AdvisedError
        Naming the option (or the shape) that cannot apply to this job, before any work.
    """
    check_choice(task, "task", TASKS)
    if bases is not None and not isinstance(bases, BasisOptions):  # (every API's options=)
        raise OptionError("options", "must be an o3d_ofp.BasisOptions, its fields as keywords "
                          f"(BasisOptions(k1=14)); got {type(bases).__name__}")  # fmt: skip
    match = MatchOptions() if match is None else match
    detail = DetailOptions() if detail is None else detail
    coordinates = task == "detail" and detail.mode == "coordinates"
    preset = "ours*" if coordinates else "ours"

    def resolved(b: BasisOptions) -> tuple[Any, ...]:
        return b.k1, b.k2, b.order, b.threshold(preset), b.matrix

    # options at their defaults (given or not) apply to any task; others to one with bases
    explicit = bases is not None and resolved(bases) != resolved(BasisOptions())
    bases = BasisOptions() if bases is None else bases
    if via_basis is not None and not isinstance(via_basis, bool):
        raise OptionError("via_basis", f"must be True, False or None; got {via_basis!r}")
    n1, n2 = V1.shape[0], None if V2 is None else V2.shape[0]
    meshes = F1 is not None and (V2 is None or F2 is not None)
    estimator = _estimator(match, given, (V1, F1, V2, F2), names)
    dense = estimator in ("full", "partial") and meshes and max(n1, n2 or 0) > DENSE_VERTICES
    dense = dense and any(e is None for e in eigenbases)
    closest = estimator == "closest" or (given is not None and given.method == "closest")
    exact = task in ("texture", "map") or (
        task == "colors" and (via_basis is False or (via_basis is None and closest))
    )
    with_bases = (task == "colors" and not exact) or coordinates
    if explicit and not with_bases:
        _refuse_bases(task, detail, closest)
    need, only_operators = _task_needs(task, (n1, n2), bases, detail, given, given_bases,
                                       with_bases, names)  # fmt: skip
    coarse_bases = tuple(
        task == "colors" and with_bases and F is not None and (n or 0) > DENSE_VERTICES
        and given_bases[i] is None and eigenbases[i] is None
        for i, (n, F) in enumerate(((n1, F1), (n2, F2)))
    )  # fmt: skip
    if with_bases:
        no_fmap = dense or estimator in ("closest", "partial") or (given and given.fmap_12 is None)
        no_fmap = no_fmap or any(coarse_bases)
        default = (preset, task if task == "colors" else "mode='coordinates'")
        if bases.preset is not None or bases.tol is not None:
            default = None
        _check_bases(bases, given_bases, bool(no_fmap), names, default=default, preset=preset)
    estimation = [0, 0]
    if estimator in ("full", "partial") and not dense:
        estimation = list(strategy_of(match).needs(n1, n2 or n1, match))
        if n2 is None:  # a collection's source: its side only
            estimation[1] = 0
    basis_k = (need[0], need[1]) if with_bases else None
    # a side whose basis is built on its coarse copy needs no full-resolution eigenpair
    need = [0 if coarse else k for k, coarse in zip(need, coarse_bases, strict=True)]
    eig_k = tuple(max(a, b) for a, b in zip(need, estimation, strict=True))
    clamp = tuple(bool(e) and e >= k for e, k in zip(estimation, need, strict=True))
    operators = tuple(only_operators and not e for e in estimation)
    return Plan(
        task=task, estimator=estimator, dense=dense, eig_k=eig_k, clamp=clamp,  # type: ignore[arg-type]
        basis_k=basis_k, order=bases.order, tol=bases.threshold(preset), matrix=bases.matrix,
        exact=exact, coarse_bases=coarse_bases, operators=operators,  # type: ignore[arg-type]
    )  # fmt: skip


def _estimator(
    match: MatchOptions, given: Correspondence | None, shapes: tuple[Any, ...], names: Any
) -> str:
    """How the map is made: given, closest points, a full or a partial estimate (checked)."""
    V1, F1, V2, F2 = shapes
    if given is None:
        if match.method == "closest":
            return "closest"
        if V2 is not None:
            match.landmarks_for(V1.shape[0], V2.shape[0])
        if not match.partial:
            return "full"
        refuse_clouds((F1,) if V2 is None else (F1, F2), names)
        if V2 is not None:
            check_partial_areas(V1, F1, V2, F2, names=names)
        return "partial"
    for name, wrong in (("partial", match.partial), ("landmarks", match.landmarks is not None)):
        if wrong:
            raise OptionError(name, Said(
                "applies to a map estimated here; the given map is used as it is (a map made "
                "with {partial} is partial already)",
            ))  # fmt: skip
    return "given"


def _task_needs(
    task: str, n: tuple[int, int | None], bases: BasisOptions, detail: DetailOptions,
    given: Correspondence | None, given_bases: Sequence[OFPBasis | None], with_bases: bool,
    names: tuple[str, str],
) -> tuple[list[int], bool]:  # fmt: skip
    """Eigenfunctions the task itself needs on each side, checked against the vertex counts.

    Also whether the task reads only the shapes' operators (the calibrated detail: an
    eigenbasis of ``k`` 1 carries them, no eigenfunction is read).
    """
    only_operators = False
    if with_bases:
        own = (bases.k1, bases.k2)
        need = [b.k if b is not None else k for b, k in zip(given_bases, own, strict=True)]
        what = ["" if b is not None else f"k{i + 1}" for i, b in enumerate(given_bases)]
    elif task == "detail" and detail.band is not None:
        need, what = [detail.band] * 2, ["band"] * 2
    elif task == "detail":  # calibrated: the shapes' operators, no eigenfunction read
        need, what = [1, 1], ["", ""]
        only_operators = True
    else:
        need, what = [0, 0], ["", ""]
    if given is not None and given.fmap_12 is not None and bases.matrix == "analytic":
        rows, cols = given.fmap_12.shape
        need = [max(need[0], cols - 1), max(need[1], rows - 1)]
    for side, (count, k, name) in enumerate(zip(n, need, what, strict=True)):
        if count is not None and name and k > max(1, count - 2):
            raise OptionError(
                name, f"({k}): {names[side]} has {count} vertices, too few for {k} "
                f"eigenfunctions (at most {max(1, count - 2)}); lower it, or give a finer "
                "mesh (Open3D's subdivide_loop or subdivide_midpoint)",
            )  # fmt: skip
    return need, only_operators


def _refuse_bases(task: str, detail: DetailOptions, closest: bool) -> None:
    """Refuse basis options given to a task that builds no OFP basis, saying why it builds none."""
    if task == "detail":
        why = Said("mode {mode!r} carries the source's detail in local frames, with no OFP basis",
                   {"mode": detail.mode})  # fmt: skip
    elif task == "colors":
        why = Said(
            "the exact pull-back ({why}) carries the colors with no OFP basis; drop it, or pass "
            "{via_basis} to transfer through the OFP bases",
            {"why": "the default with a closest-point map" if closest else Said("{pull_back}")},
        )  # fmt: skip
    else:
        why = Said("task {task!r} reads the source through the map, with no OFP basis",
                   {"task": task})  # fmt: skip
    raise OptionError("options", Said(
        "(the OFP bases' sizes and threshold) does not apply: {why}", {"why": why}
    ))  # fmt: skip


@dataclasses.dataclass(frozen=True, eq=False)
class Prepared:
    """What :func:`prepare` made: the eigenbases, the map and the OFP bases of a job."""

    eig_1: EigenBasis | None
    eig_2: EigenBasis | None
    correspondence: Correspondence
    bases: tuple[OFPBasis, OFPBasis] | None
    #: Whether each side's eigenbasis was read from the cache.
    cached: tuple[bool, bool] = (False, False)
    #: The coarse copies the plan's ``coarse_bases`` sides have their OFP basis on.
    coarse: tuple[CoarseShape | None, CoarseShape | None] = (None, None)
    #: (s1, n1) the source's values to its coarse copy (when its basis is there).
    restrict_1: sp.csr_matrix | None = None
    #: (n2, s2) the target's coarse values to its vertices (when its basis is there).
    prolong_2: sp.csr_matrix | None = None


def prepare(
    plan: Plan,
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
    *,
    match: MatchOptions | None = None,
    given: Correspondence | None = None,
    eigenbases: Sequence[EigenBasis | None] = (None, None),
    bases: Sequence[OFPBasis | None] = (None, None),
    cache_dir: Any = None,
    coarse_source: Any = None,
    progress: Callable[[str, float], None] | None = None,
    names: tuple[str, str] = ("the source", "the target"),
) -> Prepared:
    """Run a plan: the eigenbases, the map and the OFP bases it needs, each made once.

    Parameters
    ----------
    plan : Plan
        From :func:`plan_pair` for these shapes.
    V1, F1, V2, F2
        The two shapes.
    match : MatchOptions, optional
        How the map is estimated (the plan's ``match``).
    given : Correspondence, optional
        The map, when the plan's estimator is "given" or "closest" (checked against the
        shapes; its own eigenbases, when it carries them, are used).
    eigenbases : (EigenBasis or None, EigenBasis or None)
        Eigenbases the caller has (computed again, larger, when the plan needs more).
    bases : (OFPBasis or None, OFPBasis or None)
        OFP bases the caller has (a missing one is built with the plan's sizes and the given
        one's threshold, which must agree with the plan's).
    cache_dir : str or os.PathLike, optional
        Eigenbases and bases computed here are read from / written to this cache.
    coarse_source : CoarseShape, optional
        The source's coarse copy, for the dense path of a source matched onto many targets.
    progress : callable, optional
        ``progress(stage, fraction_done)`` of the map estimation.
    names : (str, str)
        How messages name the two shapes.

    Returns
    -------
    Prepared
    """
    match = MatchOptions() if match is None else match
    shapes = ((V1, F1), (V2, F2))
    have = [
        None if plan.coarse_bases[i]  # (a basis given there is the coarse copy's)
        else _given_eig(eigenbases[i], bases[i], given, i, shapes[i][0], names[i])
        for i in (0, 1)
    ]  # fmt: skip
    todo = [i for i in (0, 1) if plan.eig_k[i] and (have[i] is None or have[i].k < plan.eig_k[i])]
    for i in todo:
        if have[i] is not None:
            logger.info("the %s eigenbasis has %d eigenfunctions, %d are needed: computing it "
                        "again", ("source", "target")[i], have[i].k, plan.eig_k[i])  # fmt: skip
    _check_memory(plan, shapes, todo, bases, names)
    # The eigenbases made here keep the policy of the map's estimation, and a given one made
    # larger keeps the pieces it kept.
    policy = given.options.get("components", match.components) if given else match.components
    components = [
        "largest" if eig is not None and eig.cleaning is not None
        and eig.cleaning.report.dropped_vertices else policy
        for eig in have
    ]  # fmt: skip
    # Every shape is refused before any is solved. The dense path's estimation runs first and
    # checks both shapes itself (the check costs 0.45 s a shape at 110k vertices, 2.8 s at 440k).
    checked = plan.dense and plan.estimated and all(c == match.components for c in components)
    if len(todo) > 1 and not checked:
        for i in todo:
            check_shapes([shapes[i]], names=[names[i]], components=components[i])
    if given is not None:
        _check_given(given, V1, V2)
    coarse = _coarse(plan, shapes, match, policy, coarse_source, bases, names)
    full_bases = [plan.basis_k is not None and not plan.coarse_bases[i] and bases[i] is None
                  for i in (0, 1)]  # fmt: skip
    if cache_dir is not None and (plan.dense or any(plan.coarse_bases)) and not (
        todo or any(full_bases)
    ):
        warn(logger, Said(
            "{cache} holds full-resolution eigenbases and OFP bases; above {n} vertices the map "
            "and the bases are made on coarse copies, which it does not hold: nothing is read "
            "from it or written to it for these shapes", {"n": DENSE_VERTICES}, "cache_unused",
        ))  # fmt: skip
    corr = given
    if plan.dense:
        corr = estimate_dense(
            V1, F1, V2, F2, options=match, coarse_source=coarse[0] or coarse_source,
            coarse_target=coarse[1], progress=progress,
        )  # fmt: skip
    eigs, cached = _eigenbases(plan, shapes, have, todo, components, cache_dir, names)
    with _Ahead(plan, eigs, bases, cache_dir, shapes, components, coarse) as ahead:
        if plan.estimated and not plan.dense:
            ahead.start()
            corr = estimate(eigs[0], eigs[1], options=match, progress=progress)
            corr = dataclasses.replace(corr, eigenbases=(eigs[0], eigs[1]))
        assert corr is not None
        c1, c2 = (c if side else None for c, side in zip(coarse, plan.coarse_bases, strict=True))
        return Prepared(
            eigs[0], eigs[1], corr, ahead.result(), cached, (c1, c2),
            None if c1 is None else c1.restriction(V1, F1),
            None if c2 is None else c2.prolongation(V2),
        )  # fmt: skip


def _coarse(
    plan: Plan, shapes: tuple[tuple[Any, Any], ...], match: MatchOptions, components: str,
    coarse_source: Any, bases: Sequence[OFPBasis | None], names: tuple[str, str],
) -> list[CoarseShape | None]:  # fmt: skip
    """Coarse copies made here: the coarse-basis sides', and both when the map is dense too.

    A copy a dense match also uses gets the match's eigenfunctions and the basis's, whichever
    is more. None where none is made here (a dense match without coarse bases makes its own).
    """
    want = [plan.coarse_bases[i] or (plan.dense and any(plan.coarse_bases)) for i in (0, 1)]
    if not any(want):
        return [None, None]
    if plan.coarse_bases[0] and bases[0] is not None and coarse_source is None:
        raise ValueError("a source basis made on a coarse copy needs that copy (coarse_source)")
    return coarse_copies(
        [shape if w else None for shape, w in zip(shapes, want, strict=True)],
        k=[_coarse_k(plan, match, i) for i in (0, 1)],
        components=components, given=(coarse_source, None), names=names,
    )  # fmt: skip


def _coarse_k(plan: Plan, match: MatchOptions, side: int) -> int:
    """Eigenfunctions of a side's coarse copy: the dense match's, or its OFP basis's if more."""
    basis = plan.basis_k[side] if plan.basis_k and plan.coarse_bases[side] else 0
    return max(basis, match.zoomout_to if plan.dense else 0)


def prepare_source(
    plan: Plan,
    V1: np.ndarray,
    F1: np.ndarray | None,
    *,
    match: MatchOptions | None = None,
    cache_dir: Any = None,
) -> tuple[EigenBasis | None, OFPBasis | None, bool, CoarseShape | None]:
    """Run the source's side of a plan made without a target (a collection's shared source).

    Returns its eigenbasis (None when the plan computes none at full resolution), its OFP
    basis (None when the plan has none), whether the eigenbasis was read from the cache, and,
    on the dense path or with its basis on a coarse copy, its coarse copy (built once, for
    every target).
    """
    match = MatchOptions() if match is None else match
    shapes = ((V1, F1), (None, None))
    todo = [0] if plan.eig_k[0] else []
    eigs, cached = _eigenbases(plan, shapes, [None, None], todo, [match.components] * 2, cache_dir)
    coarse = None
    if plan.dense or plan.coarse_bases[0]:  # every target's job uses the source's copy: once
        k = [_coarse_k(plan, match, 0)]
        coarse = coarse_copies([(V1, F1)], k=k, components=match.components)[0]
    basis = None
    if plan.basis_k is not None:
        ahead = _Ahead(plan, eigs, (None, None), cache_dir, shapes, [match.components] * 2,
                       (coarse, None))  # fmt: skip
        basis = ahead._basis(0)
    return eigs[0], basis, cached[0], coarse


def _given_eig(
    eig: EigenBasis | None, basis: OFPBasis | None, given: Correspondence | None, side: int,
    V: np.ndarray, name: str,
) -> EigenBasis | None:  # fmt: skip
    """Return the eigenbasis of a side the caller has: given, a given basis's, or the map's own.

    One given (or a given basis's) of another vertex count is refused, one of another shape
    warned about; the map's own is used on the very shape it was made on only.
    """
    eig = basis.eig if eig is None and basis is not None else eig
    if eig is None:
        own = None if given is None or given.eigenbases is None else given.eigenbases[side]
        same = own is not None and own.n_vertices == V.shape[0] and same_shape(own.vertices, V)
        return own if same else None
    what = f"the {('source', 'target')[side]} eigenbasis"
    if eig.n_vertices != V.shape[0]:
        raise OptionError("eigenbases", f": {what} has {eig.n_vertices} vertices but {name} has "
                          f"{V.shape[0]}: it belongs to another shape")  # fmt: skip
    warn_other_shape(eig, V, what, name)
    return eig


def _check_given(given: Correspondence, V1: np.ndarray, V2: np.ndarray) -> None:
    """Refuse a given map of other sizes; say one made for other shapes, or that collapses."""
    given.check(V1.shape[0], V2.shape[0], source=V1, target=V2)
    if given.quality is None:  # nothing judged it yet
        why = given_map_collapse(given.p2p_21, V1.shape[0], V2.shape[0])
        if why is not None:
            warn(logger, Said("the given map is doubtful: {why}", {"why": why}, "given_collapse"))


def _check_memory(
    plan: Plan, shapes: tuple[tuple[Any, Any], ...], todo: list[int],
    bases: Sequence[OFPBasis | None], names: tuple[str, str],
) -> None:  # fmt: skip
    """Refuse, before any eigensolve, a job whose estimated peak memory exceeds what is free."""
    jobs = []
    for i in (0, 1):
        k = plan.basis_k[i] if plan.basis_k and bases[i] is None else 0
        if i in todo or k:
            n = shapes[i][0].shape[0]
            if plan.coarse_bases[i] and i not in todo:  # its basis is on its coarse copy
                n = min(n, COARSE_VERTICES)
            jobs.append((names[i], n, k or 1, plan.eig_k[i], plan.order if k else 1))
    need = sum(basis_job_bytes(n, k=k, order=o, eig_k=e) for _, n, k, e, o in jobs)
    limit = available_memory()
    if not jobs or limit is None or need <= limit:
        return
    what = " and ".join(f"{name} ({n} vertices, k={max(k, e)})" for name, n, k, e, _ in jobs)
    raise AdvisedError(Said(
        "the bases of {what} need about {need} of memory, more than the {limit} available: "
        "{" + ("lower_band" if plan.task == "detail" else "lower") + "}, or use simplified "
        "meshes (fewer vertices)" + ("; or {give_map}" if
        plan.estimated and not plan.dense else ""),  # the estimation's size: no option of theirs
        {"what": what, "need": format_bytes(need), "limit": format_bytes(limit)}, "memory",
    ))  # fmt: skip


def _eigenbases(
    plan: Plan, shapes: tuple[tuple[Any, Any], ...], have: list[EigenBasis | None],
    todo: list[int], components: Sequence[str], cache_dir: Any,
    names: tuple[str, str] = ("the source", "the target"),
) -> tuple[list[EigenBasis | None], tuple[bool, bool]]:  # fmt: skip
    """Return the plan's eigenbases and whether each was read from the cache.

    Those the caller has are kept; the others are computed side by side.
    """
    out, cached = list(have), [False, False]
    if not todo:
        return out, (False, False)

    def job(i: int) -> tuple[EigenBasis, bool]:
        V, F = shapes[i]
        options = {"k": plan.eig_k[i], "clamp_k": plan.clamp[i], "components": components[i]}
        with said_of(names[i]):
            if cache_dir is not None:
                return fetch_eigenbasis(V, F, cache_dir=cache_dir, **options)
            return eigenbasis(V, F, **options), False

    sizes = [shapes[i][0].shape[0] for i in todo]
    memory = [eigenbasis_bytes(n, plan.eig_k[i]) for n, i in zip(sizes, todo, strict=True)]
    jobs = [functools.partial(job, i) for i in todo]
    solved = run_per_shape(jobs, sizes, memory, what="eigenbases")
    for i, (eig, hit) in zip(todo, solved, strict=True):
        out[i], cached[i] = eig, hit
    return out, (cached[0], cached[1])


class _Ahead:
    """The OFP bases of a plan; the target's built in a thread while the map is estimated.

    The estimation leaves a core idle in its single-threaded stages (ZoomOut, the full
    resolution point map): :meth:`start` begins the target's basis (the larger: k2 >= k1 by
    default) there; :meth:`result` builds the rest. Shapes of
    :data:`~o3d_ofp.core._threads.PARALLEL_ROWS` vertices and more run their BLAS on both cores
    already: their bases are built one after the other. On an error the thread's basis is
    abandoned.
    """

    def __init__(
        self, plan: Plan, eigs: list[EigenBasis | None], given: Sequence[OFPBasis | None],
        cache_dir: Any, shapes: tuple[tuple[Any, Any], ...], components: Sequence[str],
        coarse: Sequence[CoarseShape | None] = (None, None),
    ) -> None:  # fmt: skip
        self.plan, self.given = plan, list(given)
        self.cache_dir, self.shapes, self.components = cache_dir, shapes, components
        # a coarse-basis side's basis is made on its coarse copy's eigenbasis
        self.eigs = [c.eig if c is not None and plan.coarse_bases[i] else e
                     for i, (e, c) in enumerate(zip(eigs, coarse, strict=True))]  # fmt: skip
        self._pool: ThreadPoolExecutor | None = None
        self._target: Future[OFPBasis] | None = None

    def __enter__(self) -> _Ahead:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=exc[0] is None, cancel_futures=True)

    def _basis(self, i: int) -> OFPBasis:
        if self.given[i] is not None:
            return self.given[i]
        eig, k = self.eigs[i], self.plan.basis_k[i]  # type: ignore[index]
        assert eig is not None
        if self.cache_dir is not None and not self.plan.coarse_bases[i]:  # full-resolution ones
            V, F = self.shapes[i]
            return fetch_basis(
                V, F, k=k, order=self.plan.order, tol=self.plan.tol, cache_dir=self.cache_dir,
                eig=eig, components=self.components[i],
            )[0]  # fmt: skip
        return ofp_basis(eig, k=min(k, eig.k), order=self.plan.order, tol=self.plan.tol)

    def start(self) -> None:
        """Start the target's basis in a thread (when there is one to build, on small shapes)."""
        plan, eig_2 = self.plan, self.eigs[1]
        if plan.basis_k is None or self.given[1] is not None or eig_2 is None:
            return
        if max(e.n_vertices for e in self.eigs if e is not None) >= PARALLEL_ROWS:
            return
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="o3d_ofp-basis")
        self._target = self._pool.submit(self._basis, 1)

    def result(self) -> tuple[OFPBasis, OFPBasis] | None:
        """Return the two bases (None when the plan has none); both built: one per core."""
        if self.plan.basis_k is None:
            return None
        if self._target is None and self.given[0] is None:
            self.start()  # (their BLAS on one thread each below PARALLEL_ROWS)
        source = self._basis(0)
        return source, self._target.result() if self._target is not None else self._basis(1)


def _check_bases(
    bases: BasisOptions, given: Sequence[OFPBasis | None], no_fmap: bool,
    names: tuple[str, str], *, default: tuple[str, str] | None, preset: str,
) -> None:  # fmt: skip
    """Refuse OFP bases of two thresholds, then the analytic matrix without a functional map.

    A given basis's threshold is compared with the other given one's, or with the plan's
    (``bases``' threshold, ``preset`` when it names none); ``default``: (preset, task) when
    the plan's is the task's default, said as such; ``no_fmap``: the map has no functional
    map between the eigenbases.
    """
    tol = bases.threshold(preset)
    held = [(i, b.tol) for i, b in enumerate(given) if b is not None]
    if len(held) == 2 and not np.isclose(held[0][1], held[1][1], rtol=1e-9):
        raise OptionError("bases", Said(
            ": the given bases of {source} and {target} were orthogonalized with thresholds "
            "{t1:g} and {t2:g}: the two bases must share one; recompute one of them",
            {"source": names[0], "target": names[1], "t1": held[0][1], "t2": held[1][1]},
        ))  # fmt: skip
    if len(held) == 1 and not np.isclose(held[0][1], tol, rtol=1e-9):
        side, t = held[0]
        preset = next((n for n, v in PRESETS.items() if np.isclose(v, t, rtol=1e-9)), None)
        setting = f"preset={preset!r}" if preset else f"tol={t:g}"
        flag = f"--preset {preset}" if preset else f"--tol {t:g}"
        raise OptionError("bases", Said(
            ": the given basis of {name} was orthogonalized with threshold {t:g}, but the "
            "{other}'s basis would be made with {tol:g}{origin}: the two bases must share one; "
            "pass {threshold}, or recompute the given basis",
            {"name": names[side], "other": ("target", "source")[side], "t": t, "tol": tol,
             "setting": setting, "flag": flag, "origin": "" if default is None else
             Said(" ({default_threshold})", {"default": default[0], "task": default[1]})},
        ))  # fmt: skip
    if bases.matrix == "analytic" and no_fmap:
        raise OptionError(
            "matrix", "='analytic' needs a functional map between the eigenbases: a map "
            "estimated for whole shapes below the dense threshold, or one given with "
            "Correspondence.from_fmap; use matrix='p2p'",
        )  # fmt: skip
