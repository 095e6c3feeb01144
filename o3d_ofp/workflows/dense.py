"""Matching dense meshes in near-linear time: estimate on coarse meshes, extend to every vertex.

The direct match of two 110k-vertex meshes spends most of its time on the 100
full-resolution eigenpairs of each shape (20-25 s per shape; 80 s at 440k vertices).
``o3d_ofp.workflows.estimate.estimate_dense`` never computes them:

1. each shape is reduced to a coarse mesh of about :data:`COARSE_VERTICES` (20000) vertices, the
   dual of its geodesic Voronoi cells (``o3d_ofp.core.multiscale.coarse_mesh``, O(n log n));
2. the whole estimation (``o3d_ofp.workflows.estimate.estimate``: descriptor fit,
   ZoomOut to 100, quality report) runs between the coarse meshes;
3. the coarse map is carried to every full-resolution vertex by
   ``o3d_ofp.core.multiscale.extend_p2p``: the coarse eigenfunctions are interpolated to
   the full vertices (the first ``EXTENSION_K``), the coarse point map's images along
   the target's surface (:meth:`CoarseShape.prolongation`), and each target vertex gets the
   exact nearest source vertex in that embedding by the cell-pruned local search (no step
   is quadratic in the vertex count); an
   estimate whose point map is not its functional map's alone passes its own ``extend``
   (the partial match: ``o3d_ofp.workflows.partial._extend_partial``).

This follows the coarse-to-fine idea of Magnet & Ovsjanikov (EG 2023) with a simpler reduced
representation (a coarse remeshing instead of their reduced functional space).

A color transfer on such a mesh needs no full-resolution eigenpair either (the plan's
``coarse_bases``): its OFP basis is built on the coarse copy, the source's values enter it as
their cells' area-weighted means (:meth:`CoarseShape.restriction`) and the target's result
leaves it interpolated along the surface (:meth:`CoarseShape.prolongation`).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from ..core._validation import check_int
from ..core.cleaning import weld_groups
from ..core.geometry import vertex_areas
from ..core.multiscale import cell_restriction, coarse_mesh, coarse_samples, surface_prolongation
from ..core.spectrum import EigenBasis, eigenbasis
from ..core.wording import Said

__all__ = [
    "COARSE_VERTICES",
    "DENSE_VERTICES",
    "EXTENSION_K",
    "CoarseShape",
    "coarse_landmarks",
    "coarse_shape",
    "shared_samples",
]

logger = logging.getLogger(__name__)

#: Meshes with more vertices than this (either shape) are matched on coarse copies (the dense
#: path of ``o3d_ofp.workflows.plan.plan_pair``). Below it the direct match is faster or
#: as fast and more precise: it keeps the exact full-resolution spectral map (measured, FAUST
#: 093 -> 087 midpoint-subdivided to 27.5k vertices: direct 0.0131 in 6.2 s, the coarse path
#: 0.0191 with the target's vertices renumbered (each copy sampled on its own), 0.0148 with
#: the two copies on the same samples (:func:`shared_samples`); tests/test_dense.py and
#: scripts/bench_match.py).
DENSE_VERTICES = 50_000
#: Vertices of each coarse mesh. Measured (FAUST 093 -> 087 subdivided to 110k vertices, map
#: error / sqrt(area) with the estimation's chosen start; the direct match of the original
#: 6890-vertex pair: 0.0166): 15000 coarse vertices 0.0235, 17500 0.0189, 20000 0.0184,
#: 22500 0.0185, 27000 0.0213 (the coarse meshes' sampling moves the error by ±0.003 around a
#: floor near 0.018); at 440k, 15000 0.0201 and 20000 0.0176. Coarse meshes and their
#: eigenpairs take 2.3 s at 15000, 3.7 s at 20000 (110k); 7000 gave 0.034-0.09 and 10000
#: 0.033-0.036. (Those runs had the final ZoomOut one eigenfunction a step; with five a step,
#: ``matching.ZOOMOUT_STEP``, 20000 gives 0.0155 at 110k and 0.0214 at 440k: bench_match.py.)
#: All these with each copy sampled on its own grid; the sampling's ±0.003 is that regime's.
COARSE_VERTICES = 20_000
#: Non-constant eigenfunctions of the coarse map's functional map that its extension to every
#: vertex compares, beside the coarse point map's images (which place each vertex; the
#: eigenfunctions keep apart parts that touch, a low-frequency matter). Measured in scratch
#: runs of the dense path (FAUST 093 -> 087 subdivided, as ``scripts/bench_match.py`` makes it;
#: map error / sqrt(area), the extension's seconds): all 99 0.0142 (2.5 s) at 110k and 0.0197
#: (13.0 s) at 440k; 30 0.0142 (1.4 s) and 0.0195 (7.7 s); 10 0.0193 (5.3 s) at 440k.
#: ``bench_match.py`` with 30: 0.0142 and 0.0195, 7.9 s and 20.2 s end to end.
EXTENSION_K = 30


@dataclasses.dataclass(frozen=True, eq=False)
class CoarseShape:
    """A shape's coarse copy and its eigenbasis, as the dense path estimates on them.

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

    def restriction(self, vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
        """(s, n) area-weighted means over the cells: the shape's values on the coarse copy.

        ``vertices`` and ``faces`` are the full shape's (the one this copy was made of).
        """
        return cell_restriction(self.cell, vertex_areas(vertices, faces), len(self.samples))

    def prolongation(self, vertices: np.ndarray) -> sp.csr_matrix:
        """(n, s) interpolation of coarse values to the full shape's ``vertices``, along it.

        Every vertex takes the value at its closest point on the coarse triangles around its
        own cell's coarse vertex (``o3d_ofp.core.multiscale.surface_prolongation``): never a
        value from a part close in space but not on the surface.
        """
        return surface_prolongation(self.vertices, self.faces, self.cell, vertices)


def coarse_shape(
    vertices: np.ndarray, faces: np.ndarray, *, k: int, coarse_vertices: int = COARSE_VERTICES,
    components: str = "auto", samples: np.ndarray | None = None,
) -> CoarseShape:  # fmt: skip
    """Build a shape's coarse copy and its eigenbasis (what the dense path needs of it).

    A source matched onto several dense targets needs this once: pass it to
    :func:`o3d_ofp.workflows.estimate.estimate_dense` as ``coarse_source``.

    Parameters
    ----------
    vertices, faces : (n, 3) ndarray of float, (m, 3) ndarray of int
        The mesh.
    k : int
        Non-constant eigenfunctions of the coarse basis (fewer when the coarse mesh is small).
    coarse_vertices : int, default :data:`COARSE_VERTICES`
        Vertices of the coarse mesh (± 10 %; a shape with no more is its own coarse mesh).
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components of the coarse mesh.
    samples : (s,) ndarray of int, optional
        The coarse vertices to use instead of ``coarse_vertices`` well-spread ones (another
        copy's, of a shape with the same triangulation: :func:`shared_samples`).

    Returns
    -------
    CoarseShape
    """
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    coarse_vertices = check_int(coarse_vertices, name="coarse_vertices", minimum=200)
    k = check_int(k, name="k", minimum=1)
    if samples is None:
        Vc, Fc, samples, cell = coarse_mesh(V, faces, min(coarse_vertices, V.shape[0]))
    else:
        Vc, Fc, samples, cell = coarse_mesh(V, faces, samples=samples)
    eig = eigenbasis(Vc, Fc, k=max(1, min(k, Vc.shape[0] - 1)), clamp_k=True, components=components)
    return CoarseShape(Vc, Fc, samples, cell, eig)


def shared_samples(
    shapes: Sequence[tuple[np.ndarray, np.ndarray | None] | None], *,
    given: Sequence[CoarseShape | None] = (None, None), coarse_vertices: int = COARSE_VERTICES,
) -> np.ndarray | None:  # fmt: skip
    """Return the coarse vertices of two meshes with one triangulation (else None).

    Two meshes with the same faces (two poses of one template, a registered dataset) get the
    same coarse vertices: the given copy's, else a grid's on the first shape. Their coarse
    copies then sample the shapes alike, as the meshes themselves do, and the coarse map can
    pair identical samplings as a direct match of the meshes does. A given copy's samples are
    taken whatever its size. Measured (FAUST 093 -> 087, one triangulation,
    midpoint-subdivided; ``scripts/bench_match.py --levels 0 1 2 3 --pyfm-levels 0 1
    --accurate-levels 0 --limit-levels 0 1 2 3``; map error / sqrt(area), the direct match at
    6890 vertices 0.0128): each copy sampled on its own 0.0142 at 110k and 0.0195 at 440k
    vertices (their grids picked the same vertex for 33 % and 8 % of the samples), the shared
    samples 0.0141 and 0.0145; the colors' error at 440k 19.62 % against 12.23 %. Renumbering
    one mesh's vertices makes the two triangulations differ: each copy then has its own grid.

    Parameters
    ----------
    shapes : sequence of two ((n, 3) ndarray, (m, 3) ndarray or None) or None
        The two meshes (None: not known here; faces None: a point cloud, never shared).
    given : sequence of two CoarseShape or None
        Copies already made of them.
    coarse_vertices : int
        Vertices of a copy made here.

    Returns
    -------
    (s,) ndarray of int64 or None
    """
    if len(shapes) != 2 or any(shape is None for shape in shapes):
        return None
    (V1, F1), (V2, F2) = shapes  # type: ignore[misc]
    if F1 is None or F2 is None:
        return None
    F1, F2 = np.asarray(F1), np.asarray(F2)
    if len(V1) != len(V2) or F1.shape != F2.shape or not np.array_equal(F1, F2):
        return None
    # and the same once repeated positions are welded (as coarse_mesh does): two STL files
    # with as many triangles list the same faces, each triangle its own three vertices, and
    # are numbered alike only if their triangles share vertices alike (both welds: 0.6 s for
    # two 440k-vertex meshes, run only when the faces are equal)
    (g1, first), (g2, _) = weld_groups(V1), weld_groups(V2)
    if not np.array_equal(g1[F1], g2[F2]):
        return None
    for copy in given:
        if copy is not None:
            return copy.samples
    # drawn on the welded vertices, as coarse_mesh counts them (an STL file of 20 000
    # positions repeated six times each is its own coarse copy)
    V = np.ascontiguousarray(V1, dtype=np.float64)[first]
    return first[coarse_samples(V, coarse_vertices)]


def coarse_landmarks(
    landmarks: np.ndarray, c1: CoarseShape, c2: CoarseShape
) -> tuple[np.ndarray, Said | None]:
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
        note = Said(
            "landmarks {given}: on the coarse copies (about {n1} and {n2} vertices) each falls "
            "on a coarse vertex an earlier landmark uses, paired there with another vertex, so "
            "the coarse estimate leaves it out (pairs a few vertices apart pin the map no better "
            "than one); give landmarks farther apart, or match at full resolution (from Python: "
            "eigenbases=, slow)",
            {"given": ", ".join(f"[{s}, {t}]" for s, t in landmarks[dropped].tolist()),
             "n1": int(c1.vertices.shape[0]), "n2": int(c2.vertices.shape[0])},
            "landmarks_dropped",
        )  # fmt: skip
    return pairs[kept], note
