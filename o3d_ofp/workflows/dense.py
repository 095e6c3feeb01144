"""Matching dense meshes in near-linear time: estimate on coarse meshes, extend to every vertex.

The direct match of two 110k-vertex meshes spends most of its time on the 100
full-resolution eigenpairs of each shape (20-25 s per shape; 80 s at 440k vertices).
:func:`match_dense` never computes them:

1. each shape is reduced to a coarse mesh of about :data:`COARSE_VERTICES` (20000) vertices, the
   dual of its geodesic Voronoi cells (:func:`o3d_ofp.core.multiscale.coarse_mesh`, O(n log n));
2. the whole estimation (``estimate``: :func:`o3d_ofp.workflows.matching.match_eigenbases`,
   descriptor fit, ZoomOut to 100, quality report) runs between the coarse meshes;
3. the coarse map is carried to every full-resolution vertex by
   :func:`o3d_ofp.core.multiscale.extend_p2p`: the coarse eigenfunctions are interpolated to
   the full vertices and each target vertex gets the exact nearest source vertex in that
   embedding by the cell-pruned local search (no step is quadratic in the vertex count); an
   estimate whose point map is not its functional map's alone passes its own ``extend``
   (the partial match: ``o3d_ofp.workflows.partial._extend_partial``).

This follows the coarse-to-fine idea of Magnet & Ovsjanikov (EG 2023) with a simpler reduced
representation (a coarse remeshing instead of their reduced functional space).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..core._progress import StageProgress
from ..core._validation import check_int
from ..core._warnings import warn
from ..core.multiscale import coarse_mesh, extend_p2p
from ..core.spectrum import EigenBasis, eigenbasis
from .eigenbases import check_shapes, eigenbasis_bytes, run_per_shape

__all__ = ["COARSE_VERTICES", "DENSE_VERTICES", "CoarseShape", "coarse_shape", "match_dense"]

logger = logging.getLogger(__name__)

#: Meshes with more vertices than this (either shape) are matched by :func:`match_dense`
#: from :func:`o3d_ofp.workflows.matching.match_arrays`. Below it the direct match is faster
#: or as fast (measured, FAUST subdivided, 27.5k vertices: direct 0.0255 error; the coarse
#: path gains little time there) and keeps the exact full-resolution spectral map.
DENSE_VERTICES = 50_000
#: Vertices of each coarse mesh. Measured (FAUST 093 -> 087 subdivided to 110k vertices, map
#: error / sqrt(area) with the estimation's chosen start; the direct match of the original
#: 6890-vertex pair: 0.0166): 15000 coarse vertices 0.0235, 17500 0.0189, 20000 0.0184,
#: 22500 0.0185, 27000 0.0213 (the coarse meshes' sampling moves the error by ±0.003 around a
#: floor near 0.018); at 440k, 15000 0.0201 and 20000 0.0176. Coarse meshes and their
#: eigenpairs take 2.3 s at 15000, 3.7 s at 20000 (110k); earlier, 7000 gave 0.034-0.09 and
#: 10000 0.033-0.036.
COARSE_VERTICES = 20_000


@dataclasses.dataclass(frozen=True, eq=False)
class CoarseShape:
    """A shape's coarse copy and its eigenbasis, as :func:`match_dense` estimates on them.

    Attributes
    ----------
    vertices : (s, 3) ndarray of float64
        Coarse vertices (a subset of the shape's).
    faces : (f, 3) ndarray of int64
        Coarse triangles.
    samples : (s,) ndarray of int64
        Index of every coarse vertex in the shape.
    cell : (n,) ndarray of int64
        Coarse vertex (cell) of every vertex of the shape.
    eig : EigenBasis
        Eigenbasis of the coarse mesh.
    """

    vertices: np.ndarray
    faces: np.ndarray
    samples: np.ndarray
    cell: np.ndarray
    eig: EigenBasis


def coarse_shape(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    k: int,
    coarse_vertices: int = COARSE_VERTICES,
    components: str = "auto",
) -> CoarseShape:
    """Build a shape's coarse copy and its eigenbasis (what :func:`match_dense` needs of it).

    A source matched onto several dense targets needs this once: pass it to
    :func:`match_dense` as ``coarse_1``.

    Parameters
    ----------
    vertices, faces : (n, 3) ndarray of float, (m, 3) ndarray of int
        The mesh.
    k : int
        Non-constant eigenfunctions of the coarse basis (fewer when the coarse mesh is small).
    coarse_vertices : int, default :data:`COARSE_VERTICES`
        Vertices of the coarse mesh (± 10 %; capped by the shape).
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components of the coarse mesh.

    Returns
    -------
    CoarseShape
    """
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    coarse_vertices = check_int(coarse_vertices, name="coarse_vertices", minimum=200)
    k = check_int(k, name="k", minimum=1)
    Vc, Fc, samples, cell = coarse_mesh(V, faces, min(coarse_vertices, V.shape[0]))
    eig = eigenbasis(Vc, Fc, k=max(1, min(k, Vc.shape[0] - 1)), clamp_k=True, components=components)
    return CoarseShape(Vc, Fc, samples, cell, eig)


def _coarse_landmarks(
    landmarks: np.ndarray, c1: CoarseShape, c2: CoarseShape
) -> tuple[np.ndarray, str | None]:
    """Carry (source, target) landmarks to the coarse vertices of their cells.

    Pairs closer than a cell apart on a shape fall on one coarse vertex there: a pair whose
    coarse vertices are both an earlier pair's is the same landmark on the coarse copies
    (merged); a pair that would pair a coarse vertex an earlier pair uses with another one is
    left out of the coarse estimate (the first given is kept). Returns the (q, 2) coarse pairs,
    q <= p, in the given order, and a note naming the pairs left out (None: none).
    """
    pairs = np.stack([c1.cell[landmarks[:, 0]], c2.cell[landmarks[:, 1]]], axis=1)
    seen_1: dict[int, int] = {}  # coarse source vertex -> coarse target vertex it is paired with
    seen_2: set[int] = set()
    kept, dropped = [], []
    for i, (a, b) in enumerate(pairs.tolist()):
        if seen_1.get(a) == b:
            continue  # the same coarse pair as an earlier landmark's
        if a in seen_1 or b in seen_2:
            dropped.append(i)
            continue
        seen_1[a] = b
        seen_2.add(b)
        kept.append(i)
    note = None
    if dropped:
        given = ", ".join(f"[{s}, {t}]" for s, t in landmarks[dropped].tolist())
        note = (
            f"landmarks {given}: on the coarse copies (about {c1.vertices.shape[0]} and "
            f"{c2.vertices.shape[0]} vertices) each falls on a coarse vertex an earlier landmark "
            "uses, paired there with another vertex, so the coarse estimate leaves it out "
            "(pairs a few vertices apart pin the map no better than one); give landmarks "
            "farther apart, or match at full resolution (from Python: eigenbases=, slow)"
        )
    return pairs[kept], note


def match_dense(
    vertices_1: np.ndarray,
    faces_1: np.ndarray,
    vertices_2: np.ndarray,
    faces_2: np.ndarray,
    *,
    estimate: Callable[..., Any],
    k: int,
    coarse_vertices: int = COARSE_VERTICES,
    components: str = "auto",
    landmarks: np.ndarray | None = None,
    progress: Callable[[str, float], None] | None = None,
    coarse_1: CoarseShape | None = None,
    extend: Callable[..., tuple[np.ndarray, Any]] | None = None,
    warn_landmarks: bool = True,
    **options: Any,
) -> Any:
    """Estimate a map between two dense meshes on coarse copies, then extend it to every vertex.

    Parameters
    ----------
    vertices_1, faces_1 : (n1, 3) ndarray of float, (m1, 3) ndarray of int
        Source mesh.
    vertices_2, faces_2 : (n2, 3) ndarray of float, (m2, 3) ndarray of int
        Target mesh.
    estimate : callable
        ``estimate(eig_1, eig_2, landmarks=..., progress=..., **options)`` returning a
        ``Correspondence`` with ``fmap_12`` (:func:`o3d_ofp.workflows.matching.match_eigenbases`,
        which passes itself: this module sits below it).
    k : int
        Non-constant eigenfunctions of the coarse bases (the size ZoomOut refines to).
    coarse_vertices : int, default :data:`COARSE_VERTICES`
        Vertices of each coarse mesh (the result has this many ± 10 %; capped by the shape).
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components of the coarse meshes (see
        :func:`o3d_ofp.eigenbasis`).
    landmarks : (p, 2) ndarray of int, optional
        Known (source, target) pairs in the full meshes' numbering (checked by the caller);
        carried to the coarse vertices of their cells (pairs that fall on one coarse vertex
        of a shape are merged, or left out of the coarse estimate when they would pair it
        with two: a warning and a note of the quality say so).
    progress : callable, optional
        Called as ``progress(stage, fraction_done)``.
    coarse_1 : CoarseShape, optional
        The source's coarse copy and eigenbasis, when the caller has them
        (:func:`coarse_shape` with the same ``k`` and ``coarse_vertices``): a source matched
        onto several targets is then reduced once.
    extend : callable, optional
        ``extend(corr, coarse_1, coarse_2, vertices_1, vertices_2)`` returning the full point
        map and the coarse Correspondence (its notes and options updated), for an estimate
        whose point map is not its ``fmap_12``'s alone (the partial match's); default:
        :func:`o3d_ofp.core.multiscale.extend_p2p` of ``corr.fmap_12``.
    warn_landmarks : bool, default True
        Warn (:class:`o3d_ofp.OFPWarning`) when landmarks are left out of the coarse estimate
        (the note is added either way); False for a caller that runs the match again.
    **options
        Passed to ``estimate``.

    Returns
    -------
    Correspondence
        ``p2p_21`` (n2,) between the full meshes; ``fmap_12`` is ``None`` (the estimated map
        lives between the coarse bases, not the full ones); ``options`` record the coarse
        sizes; ``quality`` is the coarse map's report with the coverage measured on the full
        point map.
    """
    V1 = np.ascontiguousarray(vertices_1, dtype=np.float64)
    V2 = np.ascontiguousarray(vertices_2, dtype=np.float64)
    if faces_1 is None or faces_2 is None:
        raise ValueError("match_dense needs two meshes (faces_1 and faces_2)")
    coarse_vertices = check_int(coarse_vertices, name="coarse_vertices", minimum=200)
    k = check_int(k, name="k", minimum=1)
    n1, n2 = V1.shape[0], V2.shape[0]
    if landmarks is not None:
        landmarks = np.asarray(landmarks)
        if (
            landmarks.ndim != 2
            or landmarks.shape[1] != 2
            or not np.issubdtype(landmarks.dtype, np.integer)
            or np.any(landmarks < 0)
            or np.any(landmarks.max(axis=0, initial=-1) >= [n1, n2])
        ):
            raise ValueError(
                f"landmarks must be (source, target) vertex pairs within [0, {n1}) x [0, {n2})"
            )
    if coarse_1 is not None and coarse_1.cell.shape[0] != n1:
        raise ValueError(
            f"coarse_1 was built for a shape of {coarse_1.cell.shape[0]} vertices; the source "
            f"has {n1}"
        )
    # A shape the coarse copies' eigensolves would refuse is refused before either is built.
    check_shapes(
        [(V1, faces_1), (V2, faces_2)][0 if coarse_1 is None else 1 :],
        names=("the source", "the target")[0 if coarse_1 is None else 1 :],
        components=components,
    )
    report = progress or StageProgress(logger, "match (dense)")
    # The stages below are logged as they start; their share of the run is said only when
    # this run reports its own progress: a caller's ``progress`` gives its own shares, and a
    # second one here went backwards against it (a trial's partial match: "matching: ...
    # (32%)", then "match (dense): ... (80%)", then "matching: ... (40%)").

    def share(done: float) -> str:
        return f" ({round(100 * done)}%)" if progress is None else ""

    t0 = time.perf_counter()
    coarse = functools.partial(
        coarse_shape, k=k, coarse_vertices=coarse_vertices, components=components
    )
    c1 = coarse_1
    if c1 is None:
        logger.info(
            "match (dense): coarse copies (~%d vertices) of both shapes and their eigenbases%s",
            coarse_vertices,
            share(0.0),
        )
        report("coarse copies", 0.0)
        c1, c2 = run_per_shape(
            [functools.partial(coarse, V1, faces_1), functools.partial(coarse, V2, faces_2)],
            [n1, n2],
            [eigenbasis_bytes(min(n, coarse_vertices), k) for n in (n1, n2)],
            what="coarse copies",
        )
    else:
        logger.info(
            "match (dense): the source's coarse copy is given; coarse copy of the target "
            "(~%d vertices) and its eigenbasis%s",
            coarse_vertices,
            share(0.0),
        )
        report("coarse target", 0.0)
        c2 = coarse(V2, faces_2)
    eigs = [c1.eig, c2.eig]
    coarse_landmarks, left_out = None, None
    if landmarks is not None:  # every landmark goes to the coarse vertex of its cell
        coarse_landmarks, left_out = _coarse_landmarks(landmarks, c1, c2)
        if left_out is not None and warn_landmarks:
            warn(logger, left_out)
    logger.info(
        "match (dense): estimation between the coarse meshes (%.1fs)%s",
        time.perf_counter() - t0,
        share(0.15),
    )

    def coarse_progress(stage: str, done: float) -> None:
        report(f"coarse {stage}", 0.15 + 0.65 * done)

    corr = estimate(
        eigs[0], eigs[1], landmarks=coarse_landmarks, progress=coarse_progress, **options
    )
    logger.info(
        "match (dense): extension to %d target vertices (%.1fs)%s",
        n2,
        time.perf_counter() - t0,
        share(0.8),
    )
    report("extension", 0.8)
    assert corr.fmap_12 is not None
    if extend is None:
        p2p = extend_p2p(corr.fmap_12, eigs[0], eigs[1], V1, V2)
    else:
        p2p, corr = extend(corr, c1, c2, V1, V2)
    hit = np.unique(p2p).size
    quality = corr.quality
    if quality is not None:
        quality = dataclasses.replace(quality, coverage=hit / n1, coverage_ratio=hit / min(n1, n2))
        if left_out is not None:
            quality = dataclasses.replace(quality, notes=(*quality.notes, left_out))
        # The report logged above is the coarse map's; the result's coverage is the full one.
        logger.info(
            "match (dense): the quality above is the coarse meshes'; at full resolution the "
            "map hits %d source vertices: coverage %.3f of the source's vertices (%.2f of the "
            "smaller shape's count)",
            hit,
            quality.coverage,
            quality.coverage_ratio,
        )
    logger.info("match (dense): done in %.1fs%s", time.perf_counter() - t0, share(1.0))
    report("done", 1.0)
    return dataclasses.replace(
        corr,
        p2p_21=p2p,
        n_source=n1,
        fmap_12=None,
        options={
            **corr.options,
            "landmarks": None if landmarks is None else landmarks.tolist(),
            "dense": True,
            "coarse_vertices": [int(c1.vertices.shape[0]), int(c2.vertices.shape[0])],
        },
        quality=quality,
    )
