"""Input hygiene: turn a scanned, downloaded or broken geometry into one clean surface.

Every entry point that builds a basis goes through :func:`clean_shape`. It

1. welds duplicated vertices (positions equal up to ``weld_tolerance`` times the largest side
   of the bounding box): STL triangle soups, vertices split at UV seams or normal creases,
   duplicated scan points;
2. drops degenerate faces (a repeated vertex index, also after welding) and duplicated faces
   (the same three vertices in any order);
3. removes vertices no face references;
4. resolves several connected components by the ``components`` policy (below);
5. builds the robust Laplacian of what is left (non-manifold edges and vertices, boundaries
   and slivers are kept: :mod:`robust_laplacian` handles them; boundaries get the natural
   *Neumann* condition, whereas the paper's reference code used Dirichlet conditions).

The result keeps a map back to the caller's vertices, so that every output of the library
(eigenfunctions, bases, reconstructions, point-to-point maps, transferred signals) is given on
the **original** vertices: a welded duplicate carries the value of the vertex it was merged
into, and a removed vertex (unreferenced, or in a dropped component) the value of the nearest
kept vertex in space. Removed vertices get zero mass, so they never influence a projection.

Components policy
-----------------
The Laplacian of a shape with c components has a zero eigenvalue of multiplicity c, and the
"constant first" convention (and any map between shapes) breaks. ``components`` decides:

* ``"auto"`` (default): keep the largest component (by area, by point count for clouds) when it
  holds at least :data:`AUTO_KEEP_FRACTION` of the whole (stray scan debris, a loose
  triangle), with a logged warning; otherwise raise a ``ValueError`` naming the components.
* ``"largest"``: always keep the largest component (warning when others are dropped).
* ``"error"``: raise a ``ValueError`` whenever there is more than one component.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ._rows import unique_rows
from ._validation import as_faces, as_signal, as_vertices, check_int
from ._warnings import warn
from .geometry import face_areas_normals
from .laplacian import count_components, laplacian
from .wording import AdvisedError, Said

__all__ = [
    "AUTO_KEEP_FRACTION",
    "COMPONENT_POLICIES",
    "CleanShape",
    "Cleaning",
    "CleaningReport",
    "check_shape",
    "clean_shape",
    "weld_groups",
]

logger = logging.getLogger(__name__)

#: ``components="auto"`` keeps the largest component when it holds at least this fraction of
#: the area (of the points, for a cloud): what is left out is then debris, not a second shape.
AUTO_KEEP_FRACTION = 0.9
COMPONENT_POLICIES = ("auto", "largest", "error")
# Coordinates whose extent squared (an area) and its inverse (an eigenvalue) stay well inside
# float64's range; beyond, areas or eigenvalues overflow or underflow.
_MIN_SIZE, _MAX_SIZE = 1e-100, 1e100


@dataclasses.dataclass(frozen=True)
class CleaningReport:
    """What :func:`clean_shape` changed. All counts refer to the caller's input.

    Attributes
    ----------
    input_vertices, input_faces : int
        Size of the input (``input_faces`` is 0 for a point cloud).
    vertices, faces : int
        Size of the cleaned surface the Laplacian is built on.
    merged_vertices : int
        Vertices welded into another one (duplicates).
    unreferenced_vertices : int
        Vertices no face references (removed).
    degenerate_faces, duplicate_faces : int
        Faces dropped because they repeat a vertex (after welding) or repeat another face.
    components : int
        Connected components found.
    dropped_vertices : int
        Vertices of the components that were dropped.
    dropped_fraction : float
        Fraction of the area (of the points, for a cloud) in the dropped components.
    jittered : bool
        Whether a point cloud had to be jittered (by 1e-6 of its mean spacing) for its
        Laplacian to exist.
    """

    input_vertices: int
    input_faces: int
    vertices: int
    faces: int
    merged_vertices: int = 0
    unreferenced_vertices: int = 0
    degenerate_faces: int = 0
    duplicate_faces: int = 0
    components: int = 1
    dropped_vertices: int = 0
    dropped_fraction: float = 0.0
    jittered: bool = False

    def as_array(self) -> np.ndarray:
        """Return the fields, in order, as a float64 array (for ``.npz`` files)."""
        return np.array([float(getattr(self, f.name)) for f in dataclasses.fields(self)])

    @classmethod
    def from_array(cls, values: np.ndarray) -> CleaningReport:
        """Inverse of :meth:`as_array`."""
        cast = {"int": int, "float": float, "bool": bool}
        fields = dataclasses.fields(cls)
        if len(values) != len(fields):
            raise ValueError(f"a cleaning report has {len(fields)} fields; got {len(values)}")
        return cls(**{f.name: cast[str(f.type)](v) for f, v in zip(fields, values, strict=True)})

    @property
    def changed(self) -> bool:
        """Whether the cleaned surface differs from the input."""
        return (
            self.vertices != self.input_vertices or self.faces != self.input_faces or self.jittered
        )

    def __str__(self) -> str:
        return self.said().text()

    def said(self) -> Said:
        """Return what the cleaning did, as a message (its fix worded for its reader)."""
        if not self.changed:
            return Said(f"clean input: {self.vertices} vertices, {self.faces} faces, 1 component")
        done = {"welded {} duplicated vertices": self.merged_vertices,
                "removed {} unreferenced vertices": self.unreferenced_vertices,
                "dropped {} degenerate faces": self.degenerate_faces,
                "dropped {} duplicated faces": self.duplicate_faces}  # fmt: skip
        parts = [text.format(count) for text, count in done.items() if count]
        if self.dropped_vertices:
            parts.append(
                f"kept the largest of {self.components} components: its eigenbasis leaves "
                f"out {self.dropped_vertices} vertices ({100 * self.dropped_fraction:.2g} % "
                f"of the {'area' if self.faces else 'points'}), which stay in the results with "
                "the values of their nearest kept vertex (a map, colors or detail there are "
                "not estimated: remove the small pieces, or pass {components_error} to refuse "
                "such shapes)"
            )
        if self.jittered:
            parts.append("jittered the points (degenerate neighbourhoods)")
        faces = f", {self.input_faces} -> {self.faces} faces" if self.input_faces else ""
        text = f"{'; '.join(parts)}: {self.input_vertices} -> {self.vertices} vertices{faces}"
        return Said(text, {}, "cleaned")


@dataclasses.dataclass(frozen=True, eq=False)
class Cleaning:
    """Map between the caller's vertices and the cleaned surface's.

    Attributes
    ----------
    index : (n_input,) ndarray of int64
        Cleaned vertex that stands for each input vertex (for a removed vertex: the nearest
        kept one in space).
    kept : (n_input,) ndarray of bool
        Whether an input vertex belongs to the cleaned surface (False: removed).
    representative : (n,) ndarray of int64
        Input vertex each cleaned vertex was taken from (the first of its duplicates).
    report : CleaningReport
        Counts of what changed.

    All arrays are read-only.
    """

    index: np.ndarray
    kept: np.ndarray
    representative: np.ndarray
    report: CleaningReport

    def __post_init__(self) -> None:
        for name in ("index", "kept", "representative"):
            getattr(self, name).setflags(write=False)

    @property
    def n_input(self) -> int:
        """Number of the caller's vertices."""
        return self.index.shape[0]

    @property
    def n_vertices(self) -> int:
        """Number of cleaned vertices."""
        return self.representative.shape[0]

    @property
    def multiplicity(self) -> np.ndarray:
        """(n,) number of kept input vertices that each cleaned vertex stands for."""
        return np.bincount(self.index[self.kept], minlength=self.n_vertices)

    def extend(self, values: Any) -> np.ndarray:
        """Values on the cleaned vertices, shape (n, ...) -> values on the input, (n_input, ...)."""
        values = np.asarray(values)
        if values.shape[0] != self.n_vertices:
            raise ValueError(
                f"values has {values.shape[0]} rows; the cleaned shape has {self.n_vertices}"
            )
        return values[self.index]

    def restrict(self, values: Any, *, name: str = "values") -> np.ndarray:
        """Input values, (n_input,) or (n_input, d) -> cleaned-vertex values, (n,) or (n, d).

        Each cleaned vertex gets the mean over the kept input vertices it stands for.
        """
        f = as_signal(values, self.n_input, name=name)
        out = np.zeros((self.n_vertices, *f.shape[1:]))
        np.add.at(out, self.index[self.kept], f[self.kept])
        mult = self.multiplicity.astype(np.float64)
        return out / (mult[:, None] if f.ndim == 2 else mult)


@dataclasses.dataclass(frozen=True, eq=False)
class CleanShape:
    """A cleaned surface, its Laplacian, and the map back to the input.

    Attributes
    ----------
    vertices : (n, 3) ndarray of float64
        Cleaned vertex positions (``input[cleaning.representative]``, or slightly jittered
        points for a degenerate cloud; the Laplacian was built on these).
    faces : (m, 3) ndarray of int64 or None
        Cleaned triangles indexing ``vertices``; ``None`` for a point cloud.
    stiffness : (n, n) scipy.sparse.csr_matrix
        Robust cotangent stiffness of the cleaned surface.
    mass : (n,) ndarray of float64
        Its lumped mass (all positive).
    cleaning : Cleaning
        Map to the input's vertices and report.
    """

    vertices: np.ndarray
    faces: np.ndarray | None
    stiffness: sp.csr_matrix
    mass: np.ndarray
    cleaning: Cleaning


def weld_groups(
    vertices: Any, *, tolerance: float | None = 1e-9
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Group the vertices at one position, as :func:`clean_shape` welds them.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
    tolerance : float or None, default 1e-9
        As ``weld_tolerance`` of :func:`clean_shape` (a fraction of the bounding box's largest
        side; 0: equal positions only; None: no welding).

    Returns
    -------
    group : (n,) ndarray of int
        The group of every vertex, numbered by first occurrence.
    first : (g,) ndarray of int
        The first vertex of every group.
    """
    return _weld(as_vertices(vertices), tolerance)


def _weld(vertices: np.ndarray, tolerance: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Group equal positions: returns (group of each vertex, first vertex of each group)."""
    n = vertices.shape[0]
    if tolerance is None:
        return np.arange(n), np.arange(n)
    lo = vertices.min(axis=0)
    size = float(np.max(vertices.max(axis=0) - lo))  # largest side of the bounding box
    if tolerance > 0 and size > 0:
        # Snap to a grid of cell tolerance·size. Positions within round-off of each other land
        # in the same cell except, rarely, across a cell boundary (then they stay apart, which
        # is harmless); unlike a radius search this can never blow up on a dense cluster.
        key = np.floor((vertices - lo) / size / tolerance).astype(np.int64)
        _, first, group = unique_rows(key, return_index=True, return_inverse=True)
    else:  # equal positions only
        _, first, group = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    # Number groups by first occurrence so that the cleaned order follows the input's.
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.shape[0])
    return rank[group], first[order]


def _pick_component(
    labels: np.ndarray, weights: np.ndarray, policy: str, what: str, unit: str
) -> tuple[np.ndarray | None, int, float]:
    """Apply the components policy. Returns (kept label mask or None, count, dropped fraction)."""
    count = int(labels.max()) + 1 if labels.size else 0
    if count <= 1:
        return None, count, 0.0
    totals = np.bincount(labels, weights=weights, minlength=count)
    sizes = np.bincount(labels, minlength=count)
    total = float(totals.sum())
    best = int(np.argmax(totals))
    share = float(totals[best]) / total if total > 0 else 0.0
    order = np.argsort(-totals)
    summary = ", ".join(
        f"{100 * totals[i] / total:.3g} % ({sizes[i]} {unit})" for i in order[:5]
    ) + (", ..." if count > 5 else "")
    if policy == "error" or (policy == "auto" and share < AUTO_KEEP_FRACTION):
        auto = (
            " ({components_auto} keeps the largest only when it holds at least {share:g} % of "
            "the {what})"
        )  # fmt: skip
        raise AdvisedError(Said(
            "the shape has {count} connected components (their shares of the {what}: "
            "{summary}); bases, filters and maps work on one connected surface (on pieces that "
            "do not touch the zero eigenvalue would have multiplicity {count}). Pass "
            "{components_largest} to keep the largest, or split the shape"
            + (auto if policy == "auto" else ""),
            {"count": count, "summary": summary, "what": what, "share": 100 * AUTO_KEEP_FRACTION},
            "components",
        ))  # fmt: skip
    keep = labels == best
    return keep, count, 1.0 - share


def _jitter(vertices: np.ndarray) -> np.ndarray:
    dist, _ = cKDTree(vertices).query(vertices, k=2)
    spacing = float(np.mean(dist[:, 1]))
    if spacing <= 0:
        spacing = float(np.linalg.norm(np.ptp(vertices, axis=0))) / max(vertices.shape[0], 1)
    rng = np.random.default_rng(0)  # deterministic: the same cloud always gives the same basis
    return vertices + 1e-6 * spacing * rng.standard_normal(vertices.shape)


def _check_spans_surface(vertices: np.ndarray, what: str) -> None:
    centred = vertices - vertices.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[0] == 0:
        raise ValueError(f"all {vertices.shape[0]} {what} coincide: there is no surface")
    if s[1] <= 1e-9 * s[0]:
        raise ValueError(
            f"the {vertices.shape[0]} {what} are collinear: they span no surface, so there "
            "is no Laplace-Beltrami operator"
        )


class _Topology(NamedTuple):
    """What :func:`clean_shape` settles before the Laplacian (see :func:`_topology`)."""

    V: np.ndarray  # (n_in, 3) the input positions
    F_in: np.ndarray | None  # the input faces
    group: np.ndarray  # (n_in,) welded vertex of each input vertex
    first: np.ndarray  # (n_g,) input vertex of each welded vertex
    counts: dict[str, Any]  # CleaningReport fields found so far
    keep_v: np.ndarray | None = None  # (n_g,) kept welded vertices (meshes)
    F: np.ndarray | None = None  # cleaned faces, numbered among the kept vertices (meshes)


def _topology(vertices: Any, faces: Any, weld: Any, components: str, n_neighbors: int) -> _Topology:
    """Validate, weld, drop degenerate and duplicated faces, apply the components policy.

    Everything :func:`clean_shape` can refuse about a mesh before its Laplacian (the costly
    step): a caller checks several shapes with this before computing any of them. For a point
    cloud, all but the components policy (its components are those of the Laplacian's
    neighbour graph).
    """
    V = as_vertices(vertices)
    n_in = V.shape[0]
    F_in = None if faces is None else as_faces(faces, n_in)
    if components not in COMPONENT_POLICIES:
        raise ValueError(f"components must be one of {COMPONENT_POLICIES}; got {components!r}")
    if weld is not None:  # the weld_tolerance of clean_shape
        if isinstance(weld, bool) or not np.isscalar(weld):
            raise TypeError(f"weld_tolerance must be a float or None; got {weld!r}")
        weld = float(weld)
        if not (0.0 <= weld < 1.0):
            raise ValueError(f"weld_tolerance must lie in [0, 1); got {weld}")
    check_int(n_neighbors, name="n_neighbors", minimum=3)

    with np.errstate(over="ignore"):  # a span beyond float64's range is refused just below
        size = float(np.max(np.ptp(V, axis=0)))
    if size > 0 and not (_MIN_SIZE < size < _MAX_SIZE):
        problem = "overflow" if size > 1 else "underflow"
        raise ValueError(
            f"the vertices span {size:.3g} units: areas (size²) would {problem} in float64; "
            "rescale the coordinates (the basis does not depend on the scale)"
        )
    group, first = _weld(V, weld)
    counts: dict[str, Any] = {"merged_vertices": n_in - first.shape[0]}
    Vg = V[first]
    n_g = first.shape[0]
    what = "points" if F_in is None else "vertices"
    if n_g < 3:
        raise ValueError(
            f"only {n_g} distinct {what} (of {n_in}): a basis needs at least 3"
            if n_g
            else f"the shape has no {what}"
        )

    if F_in is not None:
        F = group[F_in]
        degenerate = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
        counts["degenerate_faces"] = int(degenerate.sum())
        F = F[~degenerate]
        if F.shape[0] == 0:
            raise ValueError(
                f"all {F_in.shape[0]} faces are degenerate (they repeat a vertex once duplicated "
                "vertices are welded): there is no surface"
            )
        _, uniq = unique_rows(np.sort(F, axis=1), return_index=True)
        counts["duplicate_faces"] = F.shape[0] - uniq.shape[0]
        F = F[np.sort(uniq)]
        used = np.zeros(n_g, dtype=bool)
        used[F.reshape(-1)] = True
        counts["unreferenced_vertices"] = int(np.count_nonzero(~used[group]))
        areas = face_areas_normals(Vg, F)[0]
        # Faces whose corners all lie on a line span nothing (the cotangent Laplacian of such
        # a "mesh" still has eigenpairs: garbage). Relative to the squared extent: a rounding
        # error of collinear corners is near 1e-16 of it.
        extent = float(np.linalg.norm(np.ptp(Vg[used], axis=0))) ** 2
        if float(areas.sum()) <= 1e-12 * extent:
            raise ValueError(
                f"the {F.shape[0]} faces have no area (their vertices lie on a line): there is "
                "no surface"
            )
        # Components of the face graph (what a user sees as pieces).
        edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        graph = sp.coo_matrix(
            (np.ones(edges.shape[0]), (edges[:, 0], edges[:, 1])), shape=(n_g, n_g)
        )
        _, labels = connected_components(graph, directed=False)
        comp_of_face = labels[F[:, 0]]
        live = np.unique(comp_of_face)
        relabel = np.full(labels.max() + 1, -1)
        relabel[live] = np.arange(live.shape[0])
        face_labels = relabel[comp_of_face]
        keep_faces, n_comp, dropped = _pick_component(
            face_labels, areas, components, "area", "faces"
        )
        keep_v = used.copy()
        if keep_faces is not None:
            keep_v = np.zeros(n_g, dtype=bool)
            F = F[keep_faces]
            keep_v[F.reshape(-1)] = True
            counts["dropped_vertices"] = int(np.count_nonzero(used[group] & ~keep_v[group]))
        counts.update(components=n_comp, dropped_fraction=dropped)
        F = (np.cumsum(keep_v) - 1)[F]
        return _Topology(V, F_in, group, first, counts, keep_v, F)
    if n_g < 4:
        raise ValueError(f"a point cloud needs at least 4 distinct points; got {n_g}")
    _check_spans_surface(Vg, what)
    return _Topology(V, F_in, group, first, counts)


def check_shape(
    vertices: Any,
    faces: Any = None,
    *,
    weld_tolerance: float | None = 1e-9,
    components: str = "auto",
) -> None:
    """Refuse, cheaply, a shape :func:`clean_shape` would refuse, before any costly work.

    Runs the welding, the face checks and (for a mesh) the components policy of
    :func:`clean_shape` without building the Laplacian: a pair of shapes is checked before
    either eigensolve, so that a second shape with several components (``components=
    "error"``, or comparable ones under ``"auto"``) is refused before the first one is solved.
    A point cloud's components are only known from its Laplacian: they are not checked here.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int, optional
    weld_tolerance, components
        As in :func:`clean_shape`.

    Raises
    ------
    TypeError, ValueError
        With the message :func:`clean_shape` would give.
    """
    _topology(vertices, faces, weld_tolerance, components, 3)


def clean_shape(
    vertices: Any,
    faces: Any = None,
    *,
    weld_tolerance: float | None = 1e-9,
    components: str = "auto",
    mollify_factor: float = 1e-5,
    n_neighbors: int = 30,
) -> CleanShape:
    """Clean a mesh or point cloud and build the Laplacian of the surface that is left.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex (point) positions.
    faces : (m, 3) array_like of int, optional
        Triangles; ``None`` for a point cloud.
    weld_tolerance : float or None, default 1e-9
        Vertices closer than this fraction of the bounding box's largest side are welded (0: only
        exactly equal positions; ``None``: no welding).
    components : {"auto", "largest", "error"}, default "auto"
        What to do with several connected components (see the module's documentation).
    mollify_factor : float, default 1e-5
        Intrinsic mollification of :func:`o3d_ofp.laplacian`.
    n_neighbors : int, default 30
        Neighbours per point for a point cloud's Laplacian.

    Returns
    -------
    CleanShape
        The cleaned vertices and faces, their Laplacian and the map back to the input.

    Raises
    ------
    TypeError, ValueError
        On malformed arrays, or a shape that is no surface once cleaned (no face left,
        collinear points, too few points, several comparable components under "auto").

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> corners = np.asarray(sphere.vertices)[np.asarray(sphere.triangles)].reshape(-1, 3)
    >>> soup = np.arange(len(corners)).reshape(-1, 3)  # each triangle with its own 3 vertices
    >>> shape = ofp.clean_shape(corners, soup)
    >>> shape.vertices.shape, shape.faces.shape
    ((182, 3), (360, 3))
    >>> shape.cleaning.report.merged_vertices
    898
    """
    topo = _topology(vertices, faces, weld_tolerance, components, n_neighbors)
    V, group, first, counts = topo.V, topo.group, topo.first, dict(topo.counts)
    if topo.F is not None:
        keep_v, F = topo.keep_v, topo.F
        Vc = V[first][keep_v]
        try:
            stiffness, mass = laplacian(Vc, F, mollify_factor=mollify_factor)
        except RuntimeError as exc:  # geometry-central's assertions on impossible connectivity
            raise ValueError(f"robust-laplacian rejected the cleaned mesh: {exc}") from exc
    else:
        Vc, stiffness, mass, keep_v = _cloud_laplacian(
            topo, counts, components, mollify_factor, n_neighbors
        )
        F = None
    kept = keep_v[group]
    index = (np.cumsum(keep_v) - 1)[group]
    representative = first[keep_v]
    if not np.all(kept):  # a removed vertex takes the values of the nearest kept vertex
        index[~kept] = cKDTree(V[representative]).query(V[~kept])[1]
    n_faces = 0 if F is None else F.shape[0]
    input_faces = 0 if topo.F_in is None else topo.F_in.shape[0]
    report = CleaningReport(V.shape[0], input_faces, Vc.shape[0], n_faces, **counts)
    if report.dropped_vertices:
        warn(logger, report.said())
    elif report.changed:
        logger.info("%s", report)
    cleaning = Cleaning(index.astype(np.int64), kept, representative.astype(np.int64), report)
    return CleanShape(vertices=Vc, faces=F, stiffness=stiffness, mass=mass, cleaning=cleaning)


def _cloud_laplacian(
    topo: _Topology, counts: dict[str, Any], components: str, mollify: float, n_neighbors: int
) -> tuple[np.ndarray, sp.csr_matrix, np.ndarray, np.ndarray]:
    """Build a point cloud's Laplacian, on jittered points if need be, and pick its component.

    Returns the kept points, their stiffness and mass and the mask of the kept welded points;
    whether the points were jittered, the components found and dropped go into ``counts``.
    """
    Vc = topo.V[topo.first]
    n_g = Vc.shape[0]
    try:
        stiffness, mass = laplacian(Vc, None, mollify_factor=mollify, n_neighbors=n_neighbors)
    except (RuntimeError, ValueError) as exc:
        logger.warning("point-cloud Laplacian failed (%s); retrying on jittered points", exc)
        Vc, counts["jittered"] = _jitter(Vc), True
        try:
            stiffness, mass = laplacian(Vc, None, mollify_factor=mollify, n_neighbors=n_neighbors)
        except (RuntimeError, ValueError) as exc2:
            raise ValueError(
                f"no Laplacian for this point cloud of {n_g} distinct points, even after "
                f"jittering: {exc2}"
            ) from exc2
    labels = count_components(stiffness)[1]
    keep_v, n_comp, dropped = _pick_component(labels, np.ones(n_g), components, "points", "points")
    counts.update(components=n_comp, dropped_fraction=dropped)
    if keep_v is None:
        return Vc, stiffness, mass, np.ones(n_g, dtype=bool)
    idx = np.flatnonzero(keep_v)
    counts["dropped_vertices"] = int(np.count_nonzero(~keep_v[topo.group]))
    if idx.size < 4:
        raise ValueError(
            f"the largest of {n_comp} point-cloud components has only {idx.size} points"
        )
    # No kNN-graph edge crosses components: the restriction is the component's Laplacian (rows
    # still sum to zero).
    return Vc[idx], sp.csr_matrix(stiffness[idx][:, idx]), mass[idx], keep_v
