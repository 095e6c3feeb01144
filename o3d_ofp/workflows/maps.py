"""Maps between two shapes, as data: the Correspondence and its quality report.

A :class:`Correspondence` is what :func:`o3d_ofp.match` returns and what every transfer takes;
its :class:`MapQuality` holds the measures of the map and the verdict, each reason and note a
:class:`~o3d_ofp.core.wording.Said` (a code, values and the fixes it advises; words for Python
or the command line on demand).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import numbers
import os
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..core._atomic import atomic_path
from ..core._warnings import warn
from ..core.correspondence import check_fmap, check_p2p, p2p_from_fmap, template_pairs
from ..core.geometry import face_areas_normals
from ..core.spectrum import EigenBasis
from ..core.wording import OptionError, Said

__all__ = [
    "GIVEN_MAP_COLLAPSE",
    "TEMPLATE_SPREAD",
    "Correspondence",
    "MapQuality",
    "check_correspondence",
    "given_map_collapse",
    "keeping_landmarks",
    "same_shape",
    "shape_signature",
    "template_misfit",
    "warn_other_shape",
    "with_signatures",
]

logger = logging.getLogger(__name__)

#: Version of the ``.npz`` files of :meth:`Correspondence.save` (2: the quality's reasons and
#: notes as codes and values; files of version 1 are read, their words kept).
_FORMAT_VERSION = 2
#: A map given by the caller (a file, an array) is said to collapse when it hits fewer distinct
#: source vertices than this fraction of the smaller shape's vertex count. Lower than the
#: estimated maps' bound (``MIN_COVERAGE`` of :mod:`o3d_ofp.workflows.quality`): a right map
#: through a coarser template (scans of 50k vertices, a 6890-vertex template) hits at most the
#: template's vertices, 0.13 of them.
GIVEN_MAP_COLLAPSE = 0.02
#: Two template files (rows of both shapes' vertices at common template points) are doubted
#: when listed target vertices that are nearest neighbours go to source vertices this many
#: times farther apart, in the median (each shape's distances over sqrt(its area); over its
#: bounding-box diagonal when either is a point cloud). Measured (scratch, 2026-12-03): the
#: right files of the 20 ordered FAUST remeshed pairs and the 22 ``bcicp_dev`` pairs, all rows
#: and every 10th, 0.9-1.59 (gorilla -> human the highest; by diagonals at most 2.93); files
#: of other shapes (``bcicp_dev``'s gorilla and woman files on FAUST 093, FAUST remeshed files
#: on the 10 TOSCA animal pairs) 14.2-24.7; the right files one row apart 29.5-43.7.
TEMPLATE_SPREAD = 4.0


@dataclasses.dataclass(frozen=True)
class MapQuality:
    """Measures of a point-to-point map that need no ground truth.

    Attributes
    ----------
    coverage : float
        Fraction of the source vertices that some target vertex maps to.
    coverage_ratio : float
        Distinct source vertices hit / min(n1, n2): about 0.5 for a correct nearest-neighbour
        map, near 0 for a collapse.
    orthogonality : float
        ‖ĈᵀĈ − I‖_F / √(k+1) of the functional map Ĉ between the unit-area eigenbases (an
        isometry gives an orthogonal map); NaN when no functional map is known.
    inconsistency : float
        ‖Ĉ − Ĉ(p2p)‖_F / ‖Ĉ‖_F: how much the point map disagrees with the functional map it
        came from; NaN when no functional map is known.
    reversed_fraction : float
        Fraction of the target's triangles whose image on the source is turned over (its
        normal against the source surface's): near 0 for an orientation-preserving map, near
        1 for a mirror-image (left/right flipped) one. When either shape is a point cloud:
        the fraction of target points where the map, fitted on the point's neighbourhood, is
        a reflection (normals estimated: 0.07-0.15 for the true maps of FAUST and TOSCA
        clouds, up to 0.28 for right estimated maps).
    area_ratio : float
        Target area / source area.
    suspect : bool
        Whether the map is doubtful (see ``reasons``).
    reasons : tuple of Said
        Why it is doubtful, with the likely causes and the fix (each with its ``code`` and the
        codes of the fixes it advises; ``str()`` words it); empty when it is not.
    notes : tuple of Said
        Remarks that do not make the map suspect (e.g. very different areas).
    overlap : float or None
        For a partial map: estimated fraction of the source's area the target covers; None
        otherwise.
    reversed_of : {"triangles", "neighbourhoods"}
        What ``reversed_fraction`` counts: the target's triangles, or its points'
        neighbourhoods when either shape is a point cloud.
    distortion, stretch : float or None
        For a partial map: the geodesic distortion and the stretch its check read
        (:func:`o3d_ofp.core.partial.geodesic_distortion`,
        :func:`o3d_ofp.core.partial.map_stretch`; those of the checked map, before its
        polish; on the dense path, of the coarse copies' map); None otherwise.
    """

    coverage: float
    coverage_ratio: float
    orthogonality: float
    inconsistency: float
    reversed_fraction: float
    area_ratio: float
    suspect: bool
    reasons: tuple[Said, ...] = ()
    notes: tuple[Said, ...] = ()
    overlap: float | None = None
    reversed_of: str = "triangles"
    distortion: float | None = None
    stretch: float | None = None

    def summary(self) -> str:
        """One line: the measures and the verdict."""
        verdict = "SUSPECT" if self.suspect else "ok"
        # Each fraction says of what: the vertices hit, of the source's vertices and of the
        # smaller shape's count (unless the source is that shape: the same number twice); the
        # overlap, of the source's area.
        parts = [f"coverage {self.coverage:.3f} of the source's vertices"]
        if self.coverage_ratio != self.coverage:
            parts[0] += f" ({self.coverage_ratio:.2f} of the smaller shape's count)"
        measures = (("orthogonality", self.orthogonality), ("inconsistency", self.inconsistency),
                    (f"reversed {self.reversed_of}", self.reversed_fraction))  # fmt: skip
        # measures a map of this kind does not have (NaN) are left out
        parts += [f"{name} {value:.3f}" for name, value in measures if not math.isnan(value)]
        if not math.isnan(self.area_ratio):
            parts.append(f"area ratio {self.area_ratio:.3g}")
        if self.overlap is not None:
            parts.append(f"overlap {self.overlap:.2f} of the source's area")
        return f"map quality {verdict}: " + ", ".join(parts)

    def suspect_message(self, what: str) -> Said:
        """Return ``"<what> is suspect:"`` and each reason on its own indented line."""
        lines = "".join(f"\n  - {{r{i}}}" for i in range(len(self.reasons)))
        values = {f"r{i}": reason for i, reason in enumerate(self.reasons)}
        return Said("{what} is suspect:" + lines, {"what": what, **values}, "suspect")

    def flagged(self, reason: Said, *, first: bool = True) -> MapQuality:
        """Return this report made suspect by ``reason`` (first among the reasons, or last)."""
        reasons = (reason, *self.reasons) if first else (*self.reasons, reason)
        return dataclasses.replace(self, suspect=True, reasons=reasons)

    def noted(self, *notes: Said) -> MapQuality:
        """Return this report with ``notes`` added."""
        return dataclasses.replace(self, notes=(*self.notes, *notes))

    def codes(self) -> set[str]:
        """Return the codes of its reasons and notes (what a caller tests, never the words)."""
        return {s.code for s in (*self.reasons, *self.notes)}

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields (the reasons and notes as their templates, values and codes)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> MapQuality:
        """Return the report :meth:`as_dict` gave (or a format-1 file's, reasons as words)."""

        def said_of(item: Any) -> Said:
            if isinstance(item, str):  # format 1: the words alone
                return Said(item.replace("{", "{{").replace("}", "}}"), {}, "stored")
            return Said.from_dict(item)

        fields = dict(fields)
        for name in ("reasons", "notes"):
            fields[name] = tuple(said_of(x) for x in fields.get(name, ()))
        return cls(**fields)



@dataclasses.dataclass(frozen=True, eq=False)
class Correspondence:
    """A map between two shapes: for every target vertex, a source vertex.

    Attributes
    ----------
    p2p_21 : (n2,) ndarray of int64
        Source vertex of every target vertex, in the callers' vertex numbering (read-only).
    n_source : int
        Number of source vertices (the map's indices lie in ``[0, n_source)``).
    fmap_12 : (K+1, K+1) ndarray or None
        The functional map between the eigenbases (convention of :func:`o3d_ofp.fmap_from_p2p`),
        when the map was estimated.
    method : str
        How the map was made: ``"estimate"``, ``"partial"`` (the target a part of the
        source, :mod:`o3d_ofp.workflows.partial`), ``"closest"``, ``"given"``, ``"identity"``,
        ``"template"``.
    options : mapping
        The options used (JSON-serializable).
    quality : MapQuality or None
        The quality report (``None`` for a map given by the caller).
    faces_21 : (n2,) ndarray of int64 or None
        For a precise (surface) map: the source triangle each target vertex maps into.
    barycentric_21 : (n2, 3) ndarray of float64 or None
        Its barycentric coordinates in that triangle (rows sum to 1).
    signatures : ((s,), (s,)) ndarrays or None
        Shape signatures of the source and the target the map was made for (distances of a
        few vertices to the centroid over the RMS radius, the same for a moved, rotated or
        uniformly scaled copy; set by
        the estimation and the closest-point map): :meth:`check` warns when it is used on
        other shapes with the same vertex counts.
    eigenbases : (EigenBasis, EigenBasis) or None
        The eigenbases the map was estimated on (not saved): a transfer with this map on the
        same shapes reuses them instead of solving again.

    Examples
    --------
    >>> import os
    >>> import tempfile
    >>> import o3d_ofp as ofp
    >>> corr = ofp.Correspondence.from_p2p([2, 0, 1], 3, 3)  # target vertex i -> source vertex
    >>> corr.n_source, corr.n_target, corr.method
    (3, 3, 'given')
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "map.npz")
    ...     corr.save(path)
    ...     again = ofp.Correspondence.load(path)
    >>> again.p2p_21.tolist(), again.method
    ([2, 0, 1], 'given')
    """

    p2p_21: np.ndarray
    n_source: int
    fmap_12: np.ndarray | None = None
    method: str = "given"
    options: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    quality: MapQuality | None = None
    faces_21: np.ndarray | None = None
    barycentric_21: np.ndarray | None = None
    signatures: tuple[np.ndarray, np.ndarray] | None = None
    eigenbases: tuple[EigenBasis, EigenBasis] | None = dataclasses.field(default=None, repr=False)

    def __post_init__(self) -> None:
        n2 = np.shape(self.p2p_21)[0]
        held: dict[str, Any] = {"p2p_21": check_p2p(self.p2p_21, n2, self.n_source)}
        if self.fmap_12 is not None:
            held["fmap_12"] = np.array(self.fmap_12, dtype=np.float64)
        if (self.faces_21 is None) != (self.barycentric_21 is None):
            raise ValueError("faces_21 and barycentric_21 go together")
        if self.faces_21 is not None:
            faces = held["faces_21"] = np.array(self.faces_21, dtype=np.int64)
            bary = held["barycentric_21"] = np.array(self.barycentric_21, dtype=np.float64)
            if faces.shape != (n2,) or bary.shape != (n2, 3):
                raise ValueError(f"faces_21 and barycentric_21 must have shapes ({n2},) and "
                                 f"({n2}, 3); got {faces.shape} and {bary.shape}")  # fmt: skip
            if not np.all(np.isfinite(bary)) or np.abs(bary.sum(axis=1) - 1).max() > 1e-6:
                raise ValueError("barycentric_21 rows must be finite and sum to 1")
        if self.signatures is not None:
            pair = held["signatures"] = tuple(np.ravel(np.array(s, float)) for s in self.signatures)
            if len(pair) != 2:
                raise ValueError("signatures must be (source signature, target signature)")
        for name, value in held.items():  # read-only, as the frozen dataclass they are in
            for array in value if name == "signatures" else (value,):
                array.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def n_target(self) -> int:
        """Number of target vertices."""
        return self.p2p_21.shape[0]

    @classmethod
    def from_p2p(cls, p2p_21: Any, source: Any, target: Any) -> Correspondence:
        """Make a Correspondence of a vertex map the caller brings.

        Parameters
        ----------
        p2p_21 : (n2,) array_like of int
            For every target vertex, its source vertex (0-based).
        source, target : shape
            The shapes it maps between: Open3D geometries, (vertices, faces) tuples, (n, 3)
            vertex arrays, or vertex counts. With vertices, :meth:`check` later warns when
            the map is used on other shapes.

        Returns
        -------
        Correspondence
            ``method="given"``, no quality report.

        Examples
        --------
        >>> import numpy as np
        >>> import open3d as o3d
        >>> import o3d_ofp as ofp
        >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
        >>> moved = o3d.geometry.TriangleMesh(sphere).translate((2.0, 0.0, 0.0))
        >>> corr = ofp.Correspondence.from_p2p(np.arange(182), sphere, moved)
        >>> corr.n_source, corr.n_target, corr.quality is None
        (182, 182, True)
        """
        V1, V2 = _vertices_of(source, "source"), _vertices_of(target, "target")
        n1 = V1.shape[0] if isinstance(V1, np.ndarray) else V1
        n2 = V2.shape[0] if isinstance(V2, np.ndarray) else V2
        p2p = check_p2p(p2p_21, n2, n1)
        both = isinstance(V1, np.ndarray) and isinstance(V2, np.ndarray)
        signatures = (shape_signature(V1), shape_signature(V2)) if both else None
        return cls(p2p_21=p2p, n_source=n1, method="given", signatures=signatures)

    @classmethod
    def from_fmap(cls, fmap_12: Any, eig_1: EigenBasis, eig_2: EigenBasis) -> Correspondence:
        """Return a functional map the caller brings, with its point map (nearest neighbours).

        Parameters
        ----------
        fmap_12 : (k2+1, k1+1) array_like of float
            Map from source coefficients to target coefficients (see
            :func:`o3d_ofp.fmap_from_p2p`), at most as large as the eigenbases.
        eig_1, eig_2 : EigenBasis
            The source's and the target's eigenbases it is expressed in.

        Returns
        -------
        Correspondence
            ``method="given"`` with ``fmap_12`` and its point map; the eigenbases kept for a
            transfer.
        """
        C = np.asarray(fmap_12, dtype=np.float64)
        if C.ndim != 2 or C.shape[0] > eig_2.k + 1 or C.shape[1] > eig_1.k + 1:
            raise OptionError(
                "fmap_12",
                f"has shape {C.shape}; the eigenbases hold at most ({eig_2.k + 1}, "
                f"{eig_1.k + 1}) = (k2+1, k1+1) (target rows, source columns)",
            )
        C = check_fmap(C, *C.shape)
        p2p = p2p_from_fmap(C, eig_1, eig_2)
        return cls(
            p2p_21=p2p, n_source=eig_1.n_vertices, fmap_12=C, method="given",
            signatures=(shape_signature(eig_1.vertices), shape_signature(eig_2.vertices)),
            eigenbases=(eig_1, eig_2),
        )  # fmt: skip

    def check(
        self,
        n_source: int,
        n_target: int,
        *,
        name: str = "correspondence",
        source: Any = None,
        target: Any = None,
    ) -> None:
        """Raise ``ValueError`` unless the map goes from ``n_source`` to ``n_target`` vertices.

        With the shapes' vertices (``source``, ``target``: (n, 3) arrays) and
        ``signatures``, also warn (:class:`~o3d_ofp.OFPWarning`) when they are not the
        shapes the map was made for, up to a move, a rotation and a uniform scaling: source
        and target swapped, or another pair with the same vertex counts (all FAUST shapes
        have 6890 vertices).
        """
        if (self.n_source, self.n_target) != (n_source, n_target):
            raise ValueError(
                f"{name} maps {self.n_target} target vertices to {self.n_source} source "
                f"vertices, but the target has {n_target} and the source {n_source}: it belongs "
                "to other shapes, or to these read otherwise (a map saved by o3d-ofp indexes the "
                "vertices as o3d_ofp.read_geometry reads them; Open3D's reader with "
                "enable_post_processing=True splits an OBJ's vertices, along its UV seams or at "
                "every corner)"
            )
        said = self.mismatch(source, target, name=name)
        if said is not None:
            warn(logger, said + ". The map is used as it is")

    def mismatch(
        self, source: Any = None, target: Any = None, *, name: str = "correspondence"
    ) -> str | None:
        """Say why the map was made for other shapes than these, or None when it was not.

        Parameters
        ----------
        source, target : (n, 3) array_like, optional
            The shapes' vertices, compared with ``signatures`` up to a move, a rotation
            and a uniform scaling (a shape left out, or a map without signatures, is not
            compared).
        name : str
            How the message names the map.

        Returns
        -------
        str or None
        """
        if self.signatures is None:
            return None
        for shape, signature, side in zip(
            (source, target), self.signatures, ("source", "target"), strict=True
        ):
            if shape is None:
                continue
            if not _same_signature(shape_signature(shape), signature):
                return (
                    f"{name} was made for another {side} with {np.shape(shape)[0]} vertices "
                    "(its vertices are not where they were, even up to a move, a rotation or "
                    "a scaling): source and target swapped, another pair, a changed shape, or "
                    "the same shape with its vertices in another order (an OBJ read again)"
                )
        return None

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the correspondence to a ``.npz`` file (atomically).

        Parameters
        ----------
        path : str or os.PathLike
            Destination, ending in ``.npz``.

        Raises
        ------
        ValueError
            If the name does not end in ``.npz`` (NumPy would add it: a file other than the
            one asked for).
        FileNotFoundError
            If the destination's folder does not exist.

        Examples
        --------
        >>> import os
        >>> import tempfile
        >>> import o3d_ofp as ofp
        >>> corr = ofp.Correspondence.from_p2p([1, 1, 0], 2, 3)
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = os.path.join(folder, "map.npz")
        ...     corr.save(path)
        ...     os.path.exists(path)
        True
        """
        payload: dict[str, Any] = {
            "format_version": np.int64(_FORMAT_VERSION),
            "kind": np.array("o3d_ofp.Correspondence"),
            "p2p_21": self.p2p_21,
            "n_source": np.int64(self.n_source),
            "method": np.array(self.method),
            "options": np.array(json.dumps(dict(self.options), sort_keys=True, default=str)),
        }
        optional = {
            "fmap_12": self.fmap_12, "faces_21": self.faces_21,
            "barycentric_21": self.barycentric_21,
            **dict(zip(("signature_1", "signature_2"), self.signatures or (), strict=False)),
        }  # fmt: skip
        if self.quality is not None:
            optional["quality"] = np.array(json.dumps(self.quality.as_dict(), default=float))
        payload.update({key: value for key, value in optional.items() if value is not None})
        path = os.fspath(path)
        if not path.endswith(".npz"):
            raise ValueError(f"{path}: a correspondence is saved as .npz; name it {path}.npz")
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):  # said of the file asked for, not of a temporary one
            raise FileNotFoundError(f"{path}: the folder {folder} does not exist")
        with atomic_path(path, suffix=".npz") as tmp:
            np.savez(tmp, **payload)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Correspondence:
        """Read a correspondence written by :meth:`save`.

        Raises
        ------
        FileNotFoundError
            If there is no such file.
        ValueError
            If the file cannot be read or is not a correspondence file (the message names it).

        Examples
        --------
        >>> import os
        >>> import tempfile
        >>> import o3d_ofp as ofp
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = os.path.join(folder, "map.npz")
        ...     ofp.Correspondence.from_p2p([1, 1, 0], 2, 3).save(path)
        ...     corr = ofp.Correspondence.load(path)
        >>> corr.p2p_21.tolist(), corr.n_source
        ([1, 1, 0], 2)
        """
        import zipfile

        name = os.fspath(path)
        if os.path.isdir(name):
            raise IsADirectoryError(f"{name}: is a folder, not a correspondence file (.npz)")
        if not os.path.isfile(name):
            raise FileNotFoundError(f"{name}: no such correspondence file")
        try:
            if not zipfile.is_zipfile(name):  # np.load would speak of pickles
                raise ValueError(
                    "not an .npz archive (maps are written by Correspondence.save or --save-map)"
                )
            data = np.load(name, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise ValueError(f"{name}: cannot read a correspondence file ({exc})") from exc
        with data:
            if "kind" not in data or str(data["kind"]) != "o3d_ofp.Correspondence":
                raise ValueError(f"{name}: not an o3d_ofp correspondence file")
            if int(data["format_version"]) not in (1, _FORMAT_VERSION):
                raise ValueError(f"{name}: unknown correspondence format version")
            try:
                got = {key: data[key] for key in data.files}
                quality = json.loads(str(got["quality"])) if "quality" in got else None
                signed = "signature_1" in got
                return cls(
                    p2p_21=got["p2p_21"], n_source=int(got["n_source"]), method=str(got["method"]),
                    fmap_12=got.get("fmap_12"), options=json.loads(str(got["options"])),
                    quality=None if quality is None else MapQuality.from_dict(quality),
                    faces_21=got.get("faces_21"), barycentric_21=got.get("barycentric_21"),
                    signatures=(got["signature_1"], got["signature_2"]) if signed else None,
                )  # fmt: skip
            except (TypeError, ValueError, KeyError) as exc:
                raise ValueError(f"{name}: damaged correspondence file ({exc})") from exc


#: Vertices (evenly spaced in the vertex order) whose distances to the centroid make a shape's
#: signature.
SIGNATURE_POINTS = 32
#: Relative tolerance of a signature comparison: float32 copies of the vertices (tensor
#: meshes) differ by ~1e-7; a moved, turned or scaled copy by round-off.
SIGNATURE_RTOL = 1e-5


def shape_signature(vertices: Any) -> np.ndarray:
    """Distances of a few vertices to the centroid, over the RMS radius: (SIGNATURE_POINTS,).

    The same for a moved, rotated or uniformly scaled copy with the same vertex order; other
    shapes (another pose, source and target swapped) differ.
    """
    V = np.asarray(vertices, dtype=np.float64)
    centred = V - V.mean(axis=0)
    rms = math.sqrt(float(np.mean(np.einsum("ij,ij->i", centred, centred))))
    picks = np.linspace(0, V.shape[0] - 1, min(SIGNATURE_POINTS, V.shape[0])).astype(np.int64)
    return np.linalg.norm(centred[picks], axis=1) / max(rms, np.finfo(float).tiny)


def same_shape(vertices_a: Any, vertices_b: Any) -> bool:
    """Whether two vertex arrays are one shape up to a move, a rotation and a scaling.

    Compares their :func:`shape_signature` (same vertex counts needed); a basis computed on
    one shape and used on another with the same vertex count (source and target swapped,
    another FAUST pose) is told apart this way.
    """
    return _same_signature(shape_signature(vertices_a), shape_signature(vertices_b))


def _same_signature(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two :func:`shape_signature` values are one shape's (to :data:`SIGNATURE_RTOL`)."""
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=SIGNATURE_RTOL, atol=SIGNATURE_RTOL))


def keeping_landmarks(corr: Correspondence, landmarks: np.ndarray | None) -> Correspondence:
    """``corr`` with every landmark's target vertex sent to the source vertex given for it.

    The estimation fits the landmarks but its refinements move them: measured on the 22 pairs
    of ../shared/data/bcicp_dev with 6 true landmarks placed as ``scripts/eval_nonisometric.py``
    places them, ``ofp.match`` sent the farthest of the six 0.012-0.065 of sqrt(source area)
    away, per pair of shapes (gorilla -> human 0.027-0.065). A pair the caller knows is kept
    exactly; how far the estimate had put them is the quality's note
    (:func:`~o3d_ofp.workflows.quality.landmarks_kept`, read before this). ``landmarks``:
    (p, 2) source and target vertices of ``corr``'s shapes (None: ``corr`` itself).
    """
    if landmarks is None:
        return corr
    p2p = np.array(corr.p2p_21, dtype=np.int64)
    p2p[landmarks[:, 1]] = landmarks[:, 0]
    return dataclasses.replace(corr, p2p_21=p2p)


def with_signatures(corr: Correspondence, source: Any, target: Any) -> Correspondence:
    """``corr`` with the :func:`shape_signature` of the shapes it was made for."""
    return dataclasses.replace(
        corr, signatures=(shape_signature(source), shape_signature(target))
    )


def check_correspondence(obj: Any, name: str = "correspondence") -> Correspondence | None:
    """Return ``obj`` if it is a :class:`Correspondence` or None; else raise a TypeError.

    A bare array passed as ``correspondence=`` is the usual mistake: the message says where a
    vertex map goes instead.
    """
    if obj is not None and not isinstance(obj, Correspondence):
        raise TypeError(
            f"{name} must be an o3d_ofp Correspondence (from ofp.match or "
            f"ofp.Correspondence.load); got {type(obj).__name__} (a vertex map the caller brings: "
            "ofp.Correspondence.from_p2p(p2p_21, source, target))"
        )
    return obj


def warn_other_shape(eig: EigenBasis, vertices: np.ndarray, what: str, shape: str) -> None:
    """Warn (OFPWarning) when ``eig`` was computed on another shape than ``vertices``.

    Same vertex count, other positions even up to a move, a rotation and a scaling: source
    and target swapped, or another pose of a shape with one triangulation (FAUST).
    """
    if not same_shape(eig.vertices, vertices):
        warn(logger, Said(
            "{what} was computed on another shape than {shape} (same vertex count, other "
            "positions even up to a move, a rotation or a scaling): source and target swapped, "
            "or another shape? It is used as it is", {"what": what, "shape": shape},
            "other_shape",
        ))  # fmt: skip


def given_map_collapse(p2p_21: np.ndarray, n_source: int, n_target: int) -> Said | None:
    """Why a map given by the caller is doubtful: it collapses (:data:`GIVEN_MAP_COLLAPSE`)."""
    hit = int(np.unique(p2p_21).size)
    if hit >= GIVEN_MAP_COLLAPSE * min(n_source, n_target):
        return None
    return Said(
        "the map collapses: only {hit} distinct source vertices for {n} target vertices (a map "
        "of other shapes, or a broken one?): the result is a few flat values",
        {"hit": hit, "n": int(n_target)},
        "given_collapse",
    )


def template_misfit(
    rows_1: np.ndarray, rows_2: np.ndarray, vertices_1: np.ndarray, faces_1: np.ndarray | None,
    vertices_2: np.ndarray, faces_2: np.ndarray | None,
) -> Said | None:  # fmt: skip
    """Why two template files are doubtful for these shapes: neighbours land far apart.

    ``rows_1``, ``rows_2``: (m,) source and target vertices of the same template points (the
    files' rows, 0-based); the shapes' vertices and faces (None: a point cloud). Every listed
    target vertex is paired with its nearest listed one; a right pair of files sends the two
    about as far apart on the source, relative to the shapes' sizes, and files of other
    shapes (or rows out of step) far farther: see :data:`TEMPLATE_SPREAD`. None when the
    files pass, or list fewer than 3 target vertices.
    """
    listed, images = template_pairs(rows_1, rows_2)
    if listed.size < 3:
        return None
    meshes = faces_1 is not None and faces_2 is not None
    if meshes:
        sizes = [math.sqrt(float(face_areas_normals(V, F)[0].sum()))
                 for V, F in ((vertices_1, faces_1), (vertices_2, faces_2))]  # fmt: skip
    else:
        sizes = [float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
                 for V in (vertices_1, vertices_2)]  # fmt: skip
    points = vertices_2[listed]
    apart, nearest = cKDTree(points).query(points, k=2)
    on_target = apart[:, 1] / sizes[1]
    on_source = np.linalg.norm(vertices_1[images] - vertices_1[images[nearest[:, 1]]], axis=1)
    kept = on_target > 0  # (listed vertices at one position: no ratio)
    if not kept.any():
        return None
    spread = float(np.median(on_source[kept] / sizes[0] / on_target[kept]))
    if spread <= TEMPLATE_SPREAD:
        return None
    return Said(
        "the two template files do not fit these shapes: neighbouring template points of the "
        "target go to source vertices {spread:.1f} times as far apart, in the median (right "
        "files: at most {seen:g}; files of other shapes, or rows out of step: 14 and more); "
        "check that each file belongs to its shape and that their rows match",
        {"spread": spread, "seen": 1.6 if meshes else 2.9}, "template_misfit",
    )  # fmt: skip


def _vertices_of(shape: Any, name: str) -> np.ndarray | int:
    """Return the (n, 3) vertices of a shape given in any of the package's forms, or its count.

    ``name``: the keyword it came as, for the refusal.
    """
    if isinstance(shape, numbers.Integral) and not isinstance(shape, bool):
        return int(shape)
    if isinstance(shape, str | os.PathLike):  # files are read at the boundary, not here
        raise OptionError(name, f"={os.fspath(shape)!r} is a path: give the shape itself "
                          "(o3d_ofp.read_geometry(path)) or its vertex count")  # fmt: skip
    if isinstance(shape, tuple):
        shape = shape[0]
    with contextlib.suppress(AttributeError):
        shape = shape.vertex.positions.numpy()  # Open3D tensor geometries
    shape = getattr(shape, "vertices", getattr(shape, "points", shape))  # legacy mesh or cloud
    try:
        V = np.asarray(shape, dtype=np.float64)
    except (TypeError, ValueError):
        V = np.empty(0)
    if V.ndim != 2 or V.shape[1] != 3:
        raise OptionError(
            name, "must be a geometry, (vertices, faces), (n, 3) vertices or a count; got "
            f"{type(shape).__name__}",
        )  # fmt: skip
    return V
