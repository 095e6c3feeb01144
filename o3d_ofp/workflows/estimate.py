"""The estimator skeleton: fit starts, refine them, settle on a map, judge it, review it.

Every estimated map, full or partial, runs :func:`estimate`: the steps and their order live
here once, and a :class:`Strategy` (:class:`~o3d_ofp.workflows.matching.FullMatch`,
:class:`~o3d_ofp.workflows.partial.PartialMatch`) says how each step is done for its case.
The estimation runs on each shape's cleaned surface (:func:`on_surfaces`) and on unit-scale
copies, so the result depends neither on duplicated vertices nor on the shapes' units, place
or orientation. Meshes too large for a direct match take the dense path
(:func:`estimate_dense`: the same estimation between coarse copies, extended to every vertex,
with the strategy's optional second opinions).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Any

import numpy as np

from ..core._progress import StageProgress
from ..core._validation import check_int
from ..core._warnings import warn
from ..core.spectrum import EigenBasis, check_eigenbasis, on_cleaned_vertices
from ..core.wording import OptionError, Said
from .dense import (
    COARSE_VERTICES,
    CoarseShape,
    coarse_landmarks,
    coarse_shape,
    shared_samples,
)
from .eigenbases import check_shapes, eigenbasis_bytes, run_per_shape
from .maps import Correspondence, keeping_landmarks, shape_signature, with_signatures
from .matching import FullMatch
from .options import MatchOptions, check_bool, moved_keywords
from .partial import PartialMatch
from .quality import MapQuality, landmarks_kept, say
from .strategy import Run, Settled, Strategy

__all__ = [
    "coarse_copies",
    "estimate",
    "estimate_dense",
    "match_eigenbases",
    "on_surfaces",
    "strategy_of",
]

logger = logging.getLogger(__name__)


def strategy_of(options: MatchOptions) -> Strategy:
    """Return the strategy of an estimation with these options (full or partial)."""
    return PartialMatch() if options.partial else FullMatch()


def estimate(
    eig_1: EigenBasis, eig_2: EigenBasis, *, options: MatchOptions | None = None,
    strategy: Strategy | None = None, progress: Callable[[str, float], None] | None = None,
    warn_suspect: bool = True,
) -> Correspondence:  # fmt: skip
    """Estimate a map between two eigenbases: the skeleton every estimation runs.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases, each as large as the strategy needs
        (:meth:`Strategy.needs`: a smaller basis is refused, never silently downgraded).
    options : MatchOptions, optional
        The estimation's options (default ``MatchOptions()``); ``landmarks`` are checked
        against the bases' vertex counts.
    strategy : Strategy, optional
        How the steps are done (default :func:`strategy_of` the options).
    progress : callable, optional
        ``progress(stage, fraction_done)`` (default: logged every few seconds at INFO).
    warn_suspect : bool, default True
        Warn (:class:`o3d_ofp.OFPWarning`) about a suspect map; False for a caller that judges
        it again (its reasons are in ``quality`` either way).

    Returns
    -------
    Correspondence
        ``p2p_21`` on the input vertices, the functional map, the options and the quality.
    """
    options = MatchOptions() if options is None else options
    strategy = strategy_of(options) if strategy is None else strategy
    eig_1, eig_2 = check_eigenbasis(eig_1, "eig_1"), check_eigenbasis(eig_2, "eig_2")
    need = strategy.least(eig_1.n_vertices, eig_2.n_vertices, options)
    for name, eig, k in (("source", eig_1, need[0]), ("target", eig_2, need[1])):
        if eig.k < k:
            raise OptionError(
                "eigenbases",
                f": the {name} eigenbasis has {eig.k} eigenfunctions but the {strategy.title} "
                f"needs {k}: compute it with eigenbasis(..., k={options.zoomout_to}) (or lower "
                "zoomout_to / k_fit knowingly)",
            )
    strategy.check(eig_1, eig_2)
    landmarks = options.landmarks_for(eig_1.n_vertices, eig_2.n_vertices)

    def on_surface(s1: EigenBasis, s2: EigenBasis, lm: np.ndarray | None) -> Correspondence:
        return _estimate(s1, s2, strategy, lm, options, progress, warn_suspect)

    return on_surfaces(eig_1, eig_2, on_surface, landmarks)


@moved_keywords(
    "k_fit", "zoomout_to", "zoomout_subsample", "descriptors", "w_orient",
    landmarks="options=o3d_ofp.MatchOptions(landmarks=...)",
)
def match_eigenbases(
    eig_1: EigenBasis, eig_2: EigenBasis, *, options: MatchOptions | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> Correspondence:  # fmt: skip
    """Estimate a map between two shapes from their eigenbases (:func:`o3d_ofp.match` on arrays).

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases, with at least ``options.zoomout_to`` non-constant
        eigenfunctions each (fewer only when a shape has fewer vertices): a smaller basis is an
        error, never a silent downgrade.
    options : MatchOptions, optional
        Landmarks, a partial match (the target a part of the source, same units), the fit and
        ZoomOut sizes (default ``MatchOptions()``; ``method="closest"`` needs the Open3D-level
        :func:`o3d_ofp.match`).
    progress : callable, optional
        Called as ``progress(stage, fraction_done)`` at each stage.

    Returns
    -------
    Correspondence
        ``p2p_21``, the functional map, the options and the quality report. A suspect map is
        warned about (:class:`o3d_ofp.OFPWarning`), naming the likely causes and the fix.

    Notes
    -----
    The estimation runs on each shape's cleaned surface (one vertex per welded group, e.g. the
    copies of an OBJ's vertices along its UV seams) and the point map is carried back to the
    input vertices; the quality report's counts (coverage) are those of the surfaces.

    References
    ----------
    .. [1] S. Melzi et al., "ZoomOut: Spectral Upsampling for Efficient Shape Correspondence",
       ACM TOG 38(6), 2019.
    .. [2] J. Ren et al., "Continuous and Orientation-preserving Correspondences via
       Functional Maps", ACM TOG 37(6), 2018.

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> xyz = np.asarray(sphere.vertices)
    >>> shape = o3d.geometry.TriangleMesh(sphere)  # a bumpy ellipsoid with no symmetry
    >>> bumps = 0.2 * xyz[:, [1, 2, 0]] ** 2
    >>> shape.vertices = o3d.utility.Vector3dVector(xyz * [1.0, 0.7, 0.5] + bumps)
    >>> moved = o3d.geometry.TriangleMesh(shape)
    >>> _ = moved.rotate(moved.get_rotation_matrix_from_xyz((0.3, 0.2, 0.1)), center=(0, 0, 0))
    >>> eig_1, eig_2 = ofp.eigenbasis(shape, k=10), ofp.eigenbasis(moved, k=10)
    >>> corr = ofp.match_eigenbases(eig_1, eig_2, options=ofp.MatchOptions(k_fit=6, zoomout_to=10))
    >>> corr.p2p_21.shape, corr.method, corr.quality.suspect
    ((182,), 'estimate', False)
    >>> bool((corr.p2p_21 == np.arange(182)).mean() > 0.9)
    True
    """
    if options is not None and options.method != "estimate":
        raise OptionError("method", "='closest' needs the shapes' surfaces: o3d_ofp.match")
    return estimate(eig_1, eig_2, options=options, progress=progress)


def _estimate(
    eig_1: EigenBasis, eig_2: EigenBasis, strategy: Strategy, landmarks: np.ndarray | None,
    options: MatchOptions, progress: Callable[[str, float], None] | None, warn_suspect: bool,
) -> Correspondence:  # fmt: skip
    """:func:`estimate` between two cleaned surfaces."""
    report = progress or StageProgress(logger, strategy.title)
    run = Run(eig_1, eig_2, *strategy.scaled(eig_1, eig_2), landmarks, options, report)
    settled, quality = _steps(strategy, run)
    if landmarks is not None and strategy.rival_without_landmarks(run, quality):
        # the same estimation without them (the shapes' bases reused), judged by the strategy
        logger.info("%s: the map the landmarks drive is doubtful: estimating it without them "
                    "too", strategy.title)  # fmt: skip
        free_run = Run(eig_1, eig_2, run.u1, run.u2, None, options,
                       lambda stage, done: report(f"without the landmarks: {stage}", done),
                       state={"landmarks_given": True})  # fmt: skip
        settled, quality = strategy.against_free(run, settled, quality, *_steps(strategy, free_run))
    if landmarks is not None:  # how far the estimate put them; on_surfaces then keeps them
        quality = landmarks_kept(quality, settled.p2p_21, landmarks, run.u1.vertices)
    say(strategy.title, strategy.what, quality, warn_suspect=warn_suspect)
    report("done", 1.0)
    return Correspondence(
        p2p_21=settled.p2p_21, n_source=eig_1.n_vertices, fmap_12=settled.fmap_12,
        method=strategy.method, options=strategy.options(run, settled), quality=quality,
        signatures=(shape_signature(eig_1.vertices), shape_signature(eig_2.vertices)),
    )  # fmt: skip


def _steps(strategy: Strategy, run: Run) -> tuple[Settled, MapQuality]:
    """Run a strategy's steps: the starts, their refinement, the choice, its judgement, review."""
    report = run.report
    starts = strategy.starts(run)
    first, share = strategy.refine_share
    # The starts are independent and their BLAS runs on one thread: two at a time, one per core.
    with ThreadPoolExecutor(max_workers=2) as pool:
        jobs = [pool.submit(strategy.refine, run, i, start) for i, start in enumerate(starts)]
        for done, _ in enumerate(as_completed(jobs)):
            report(f"ZoomOut {done + 1}/{len(jobs)}", first + share * done / len(jobs))
        refined = [job.result() for job in jobs]
    settled = strategy.settle(run, starts, refined)
    quality = strategy.judge(run, settled)
    return strategy.review(run, settled, quality)


def on_surfaces(
    eig_1: EigenBasis, eig_2: EigenBasis,
    match: Callable[[EigenBasis, EigenBasis, np.ndarray | None], Correspondence],
    landmarks: np.ndarray | None,
) -> Correspondence:  # fmt: skip
    """Run an estimation on the shapes' cleaned surfaces; its map back on the input vertices.

    ``match(s1, s2, landmarks)`` runs between :func:`o3d_ofp.core.spectrum.on_cleaned_vertices`
    of both bases (one vertex per welded group: an OBJ's copies along its UV seams, an STL's
    triangle soup; else the geodesic graphs have isolated copies and the spectral searches
    meet ties), the landmarks carried to the surfaces' vertices; the point map is returned on
    the input vertices, with the input's landmarks and signatures.
    """
    s1, rep_1 = on_cleaned_vertices(eig_1)
    s2, rep_2 = on_cleaned_vertices(eig_2)
    if rep_1 is None and rep_2 is None:
        corr = keeping_landmarks(match(eig_1, eig_2, landmarks), landmarks)
        return with_signatures(corr, eig_1.vertices, eig_2.vertices)
    on_surface, left_out = landmarks, None
    if landmarks is not None:  # each input vertex stands for its surface vertex
        on_surface = landmarks.copy()
        outside = np.zeros(len(landmarks), dtype=bool)
        for col, eig, rep in ((0, eig_1, rep_1), (1, eig_2, rep_2)):
            if rep is not None:
                on_surface[:, col] = eig.cleaning.index[landmarks[:, col]]
                outside |= ~np.asarray(eig.cleaning.kept)[landmarks[:, col]]
        if outside.any():  # (a left-out vertex stands for its nearest kept one: a wrong pair)
            left_out = Said(
                "landmarks {given}: on a piece the eigenbasis left out (components='auto' or "
                "'largest' keeps the largest connected component), so the estimate leaves them "
                "out; the result keeps them as given",
                {"given": ", ".join(f"[{a}, {b}]" for a, b in landmarks[outside].tolist())},
                "landmarks_outside",
            )  # fmt: skip
            warn(logger, left_out)
            on_surface = on_surface[~outside] if not outside.all() else None
    logger.info(
        "match: on the cleaned surfaces (%d and %d of %d and %d vertices)",
        s1.n_vertices, s2.n_vertices, eig_1.n_vertices, eig_2.n_vertices,
    )  # fmt: skip
    corr = match(s1, s2, on_surface)
    if left_out is not None and corr.quality is not None:
        corr = dataclasses.replace(corr, quality=corr.quality.noted(left_out))
    p2p = corr.p2p_21 if rep_1 is None else rep_1[corr.p2p_21]
    if rep_2 is not None:
        p2p = p2p[eig_2.cleaning.index]
    given = None if landmarks is None else landmarks.tolist()
    corr = dataclasses.replace(corr, p2p_21=p2p, n_source=eig_1.n_vertices,
                               options={**corr.options, "landmarks": given})  # fmt: skip
    return with_signatures(keeping_landmarks(corr, landmarks), eig_1.vertices, eig_2.vertices)


def estimate_dense(
    vertices_1: np.ndarray, faces_1: np.ndarray, vertices_2: np.ndarray, faces_2: np.ndarray, *,
    options: MatchOptions | None = None, coarse_vertices: int | None = None,
    coarse_source: Any = None, coarse_target: Any = None,
    progress: Callable[[str, float], None] | None = None, opinions: bool = True,
) -> Correspondence:  # fmt: skip
    """Estimate a map between two dense meshes on coarse copies (the dense path).

    The match between coarse copies (:mod:`o3d_ofp.workflows.dense`) with the options'
    strategy, then (``opinions``) the strategy's check against matches on other coarse copies
    (the partial match's second and third opinions; none for a full match).

    Parameters
    ----------
    vertices_1, faces_1, vertices_2, faces_2
        The two meshes.
    options : MatchOptions, optional
        The estimation's options (``landmarks`` in the meshes' numbering).
    coarse_vertices : int, optional
        Vertices of each coarse copy (default :data:`o3d_ofp.workflows.dense.COARSE_VERTICES`).
    coarse_source : CoarseShape, optional
        The source's coarse copy, built once for several targets.
    coarse_target : CoarseShape, optional
        The target's coarse copy (made by a caller that uses it after the match too).
    progress : callable, optional
        ``progress(stage, fraction_done)``.
    opinions : bool, default True
        Run the strategy's second opinions.

    Returns
    -------
    Correspondence
    """
    options = MatchOptions() if options is None else options
    strategy = strategy_of(options)
    first = COARSE_VERTICES if coarse_vertices is None else coarse_vertices
    check_int(first, name="coarse_vertices", minimum=200)
    check_bool(opinions, "opinions")
    if faces_1 is None or faces_2 is None:
        raise OptionError("faces_1", "and faces_2: the dense path matches two meshes (a point "
                          "cloud has no coarse copy)")  # fmt: skip
    landmarks = options.landmarks_for(len(vertices_1), len(vertices_2))

    whole = progress or StageProgress(logger, strategy.title)

    def again(size: int, share: tuple[float, float], prefix: str) -> Correspondence:
        """Run the dense match on coarse copies of ``size`` vertices, its progress in ``share``."""
        report = progress
        if share != (0.0, 1.0):  # one of several runs: its stages in its share of the whole

            def report(stage: str, done: float) -> None:
                last = stage == "done" and sum(share) < 1  # not the end of the whole
                whole(prefix + ("first match done" if last else stage), share[0] + share[1] * done)

        corr = _match_dense(
            vertices_1, faces_1, vertices_2, faces_2, strategy=strategy, options=options,
            landmarks=landmarks, coarse_vertices=size, progress=report,
            coarse=(coarse_source, coarse_target) if size == first else (None, None),
            quiet=size != first,
        )  # fmt: skip
        return with_signatures(corr, vertices_1, vertices_2)  # not the coarse meshes'

    shapes = (vertices_1, faces_1, vertices_2, faces_2)
    # the landmarks were checked on the coarse map (and by a partial match on the full one)
    return keeping_landmarks(strategy.dense(again, first, shapes, whole, opinions=opinions),
                             landmarks)  # fmt: skip


def _match_dense(
    vertices_1: np.ndarray, faces_1: np.ndarray, vertices_2: np.ndarray, faces_2: np.ndarray, *,
    strategy: Strategy, options: MatchOptions, landmarks: np.ndarray | None, coarse_vertices: int,
    progress: Callable[[str, float], None] | None,
    coarse: tuple[CoarseShape | None, CoarseShape | None], quiet: bool,
) -> Correspondence:  # fmt: skip
    """Estimate a map between two dense meshes on coarse copies, then extend it to every vertex.

    The strategy's :meth:`~o3d_ofp.workflows.strategy.Strategy.for_coarse` runs between coarse
    copies of about ``coarse_vertices`` vertices (``coarse``: copies already made, such as a
    source's made once for several targets), with eigenbases of at least
    ``options.zoomout_to`` functions; ``landmarks`` (in the
    full meshes' numbering) go to the coarse vertices of their cells (pairs that fall on one
    coarse vertex are merged, or left out when they would pair it twice: a note, and a warning
    unless ``quiet``, which also silences a suspect map: a run that checks another). Its
    :meth:`~o3d_ofp.workflows.strategy.Strategy.extend` carries the map to every vertex.

    Returns
    -------
    Correspondence
        ``p2p_21`` (n2,) between the full meshes; ``fmap_12`` is ``None`` (the map lives
        between the coarse bases); ``options`` record the coarse sizes; ``quality`` is the
        coarse map's report with the coverage measured on the full point map.
    """
    V1 = np.ascontiguousarray(vertices_1, dtype=np.float64)
    V2 = np.ascontiguousarray(vertices_2, dtype=np.float64)
    n1, n2 = V1.shape[0], V2.shape[0]
    report = progress or StageProgress(logger, "match (dense)")

    def say(what: str, done: float, *args: Any) -> None:  # a caller's progress: its own shares
        logger.info("match (dense): " + what + "%s", *args,
                    "" if progress else f" ({round(100 * done)}%)")  # fmt: skip

    t0 = time.perf_counter()
    c1, c2 = _coarse_copies(
        (V1, faces_1), (V2, faces_2), coarse, coarse_vertices, options, say, report
    )
    lm_coarse, left_out = None, None
    if landmarks is not None:  # every landmark goes to the coarse vertex of its cell
        lm_coarse, left_out = coarse_landmarks(landmarks, c1, c2)
        if left_out is not None and not quiet:
            warn(logger, left_out)
    say("estimation between the coarse meshes (from %.1f s)", 0.15, time.perf_counter() - t0)
    corr = estimate(
        c1.eig, c2.eig, options=dataclasses.replace(options, landmarks=lm_coarse),
        strategy=strategy.for_coarse(), warn_suspect=not quiet,
        progress=lambda stage, done: report(f"coarse {stage}", 0.15 + 0.65 * done),
    )  # fmt: skip
    say("extension to %d target vertices (from %.1f s)", 0.8, n2, time.perf_counter() - t0)
    report("extension", 0.8)
    p2p, corr = strategy.extend(corr, c1, c2, V1, V2)
    hit = np.unique(p2p).size
    quality = corr.quality
    if quality is not None:
        quality = dataclasses.replace(quality, coverage=hit / n1, coverage_ratio=hit / min(n1, n2))
        quality = quality if left_out is None else quality.noted(left_out)
        # The report logged above is the coarse map's; the result's coverage is the full one.
        logger.info("match (dense): the quality above is the coarse meshes'; at full resolution "
                    "the map hits %d source vertices: coverage %.3f of the source's vertices "
                    "(%.2f of the smaller shape's count)", hit, quality.coverage,
                    quality.coverage_ratio)  # fmt: skip
    say("done in %.1fs", 1.0, time.perf_counter() - t0)
    report("done", 1.0)
    sizes = [int(c1.vertices.shape[0]), int(c2.vertices.shape[0])]
    return dataclasses.replace(
        corr, p2p_21=p2p, n_source=n1, fmap_12=None, quality=quality,
        options={**corr.options, "landmarks": None if landmarks is None else landmarks.tolist(),
                 "dense": True, "coarse_vertices": sizes},
    )  # fmt: skip


def _coarse_copies(
    source: tuple[np.ndarray, np.ndarray], target: tuple[np.ndarray, np.ndarray],
    given: tuple[CoarseShape | None, CoarseShape | None], size: int, options: MatchOptions,
    say: Callable[..., None], report: Callable[[str, float], None],
) -> tuple[CoarseShape, CoarseShape]:  # fmt: skip
    """Return the coarse copies of both shapes for the dense match (those not ``given``)."""
    if all(c is not None for c in given):
        say("reusing the coarse copies made before the match", 0.0)
    elif given[0] is not None:
        say("the source's coarse copy is given; coarse copy of the target (~%d vertices) and "
            "its eigenbasis", 0.0, size)  # fmt: skip
    else:
        say("coarse copies (~%d vertices) of both shapes and their eigenbases", 0.0, size)
    report("coarse copies", 0.0)
    c1, c2 = coarse_copies((source, target), k=(options.zoomout_to,) * 2, size=size,
                           components=options.components, given=given)  # fmt: skip
    assert c1 is not None and c2 is not None
    return c1, c2


def coarse_copies(
    shapes: Sequence[tuple[np.ndarray, np.ndarray] | None], *, k: Sequence[int],
    size: int | None = None, components: str = "auto",
    given: Sequence[CoarseShape | None] = (None, None),
    names: Sequence[str] = ("the source", "the target"),
) -> list[CoarseShape | None]:  # fmt: skip
    """Coarse copies of shapes (:func:`o3d_ofp.workflows.dense.coarse_shape`), side by side.

    Parameters
    ----------
    shapes : sequence of ((n, 3) ndarray, (m, 3) ndarray) or None
        The meshes (None: no copy wanted for that one).
    k : sequence of int
        Eigenfunctions of each copy's basis.
    size : int, optional
        Vertices of each copy (default :data:`~o3d_ofp.workflows.dense.COARSE_VERTICES`;
        a given copy's count instead where the two shapes share one triangulation).
    components : {"auto", "largest", "error"}
        The components policy.
    given : sequence of CoarseShape or None
        Copies already made (kept; one built for another vertex count is refused). Two
        shapes with one triangulation get the same coarse vertices
        (:func:`~o3d_ofp.workflows.dense.shared_samples`).
    names : sequence of str
        How messages name the shapes.

    Returns
    -------
    list of CoarseShape or None
        One per shape (None where the shape is None).

    Raises
    ------
    ValueError
        A given copy of another shape, or a shape the eigensolves would refuse: before any
        copy is built.
    """
    for shape, copy, name in zip(shapes, given, names, strict=False):
        if copy is not None and shape is not None and copy.cell.shape[0] != len(shape[0]):
            raise ValueError(f"the coarse copy of {name} was built for a shape of "
                             f"{copy.cell.shape[0]} vertices; it has {len(shape[0])}")  # fmt: skip
    size = COARSE_VERTICES if size is None else size
    todo = [i for i, shape in enumerate(shapes) if shape is not None and given[i] is None]
    check_shapes([shapes[i] for i in todo], names=[names[i] for i in todo],  # type: ignore[misc]
                 components=components)  # fmt: skip
    samples = shared_samples(shapes, given=given, coarse_vertices=size) if todo else None
    jobs = [functools.partial(coarse_shape, *shapes[i], k=k[i], coarse_vertices=size,  # type: ignore[misc]
                              components=components, samples=samples) for i in todo]  # fmt: skip
    n = [len(shapes[i][0]) for i in todo]  # type: ignore[index]
    made = size if samples is None else samples.size
    memory = [eigenbasis_bytes(min(m, made), k[i]) for m, i in zip(n, todo, strict=True)]
    built = run_per_shape(jobs, n, memory, what="coarse copies") if todo else []
    out = [given[i] if i < len(given) else None for i in range(len(shapes))]
    for i, copy in zip(todo, built, strict=True):
        out[i] = copy
    return out
