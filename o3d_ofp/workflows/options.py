"""The options of a job, checked once where the caller hands them over.

Each options object validates every field in ``__post_init__`` and raises
:class:`~o3d_ofp.core.wording.OptionError` naming the field (the command line maps the field to
its flag through one table); code below trusts them. The defaults written here are the only
copies of the package's defaults (the paper's K = 30 / 40 for humans: ``k1=29``, ``k2=39``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from ..core._validation import check_int
from ..core._warnings import outside_the_package
from ..core.orthogonalize import resolve_tol
from ..core.spectrum import DEFAULT_K
from ..core.wording import OptionError, Said

__all__ = [
    "COMPONENTS",
    "DETAIL_MODES",
    "ESTIMATION_K",
    "FIT_K",
    "MAX_AMOUNT",
    "BasisOptions",
    "DetailOptions",
    "MatchOptions",
    "check_bool",
    "check_choice",
    "check_number",
    "deprecated_choice",
    "required_k",
    "same_frame_conflict",
]

#: Non-constant eigenfunctions an estimated map is refined to by ZoomOut (pyFM's standard
#: pipeline refines 30 -> 100 with the constant).
ESTIMATION_K = 99
#: Size of the map optimized from descriptors before ZoomOut (the paper's K = 30).
FIT_K = DEFAULT_K
#: Policies for several connected components (see :func:`o3d_ofp.eigenbasis`).
COMPONENTS = ("auto", "largest", "error")
#: Largest ``amount`` of a detail transfer: a detail exaggerated ten times is no longer the
#: source's detail.
MAX_AMOUNT = 10.0
#: Detail transfer modes (see :mod:`o3d_ofp.workflows.detail`).
DETAIL_MODES = ("add", "replace-detail", "coordinates")
#: Deprecated names of options' values: (option, old value) -> new value.
_RENAMED = {("mode", "replace"): "coordinates"}


_Function = TypeVar("_Function", bound=Callable[..., Any])


def required_k(n_vertices: int, wanted: int = ESTIMATION_K) -> int:
    """Eigenfunctions a shape of ``n_vertices`` vertices can give of ``wanted``: at most n - 1."""
    return max(1, min(wanted, n_vertices - 1))


def check_bool(value: Any, name: str) -> bool:
    """Return ``value`` if it is True or False, else raise an OptionError naming ``name``."""
    if not isinstance(value, bool | np.bool_):
        raise OptionError(name, f"must be True or False; got {value!r}")
    return bool(value)


def check_choice(value: Any, name: str, choices: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of ``choices``, else raise an OptionError naming ``name``."""
    if not isinstance(value, str) or value not in choices:
        raise OptionError(name, f"must be one of {', '.join(map(repr, choices))}; got {value!r}")
    return value


#: Keywords the functions took before the options objects (CHANGELOG, "Removed"), and what
#: replaces them.
MOVED = {
    **{k: "correspondence=o3d_ofp.match(source, target, " + k + "=...)"
       for k in ("landmarks", "partial", "components")},
    "p2p_21": "correspondence=o3d_ofp.Correspondence.from_p2p(p2p_21, source, target)",
    "fmap_12": "correspondence=o3d_ofp.Correspondence.from_fmap(fmap_12, eig_1, eig_2)",
    "eigenbases": "bases=(eig_1, eig_2)",
    "method": "options=o3d_ofp.BasisOptions(matrix=...)",
    "k_low": "band=",
    **{k: f"options=o3d_ofp.BasisOptions({k}=...)" for k in ("k1", "k2", "order", "preset", "tol")},
    **{k: f"options=o3d_ofp.MatchOptions({k}=...)"
       for k in ("k_fit", "zoomout_to", "zoomout_subsample", "descriptors", "w_orient")},
}  # fmt: skip


def moved_keywords(*names: str, **instead: str) -> Callable[[_Function], _Function]:
    """Make a function refuse its former keywords with what replaces each.

    ``names``: replaced as :data:`MOVED` says; ``instead``: keyword -> its replacement here.
    Python's own error would only say "unexpected keyword argument"; the signature is kept.
    """
    where = {**{name: MOVED[name] for name in names}, **instead}

    def wrap(function: _Function) -> _Function:
        @functools.wraps(function)
        def call(*args: Any, **kwargs: Any) -> Any:
            for name, use in where.items():
                if name in kwargs:
                    raise TypeError(f"{function.__name__}() no longer takes {name}=: use {use} "
                                    "(see the CHANGELOG)")  # fmt: skip
            return function(*args, **kwargs)

        return call  # type: ignore[return-value]

    return wrap


def deprecated_choice(name: str, value: Any) -> Any:
    """Return the value a deprecated value of option ``name`` now has (with a warning).

    The one place deprecated option values are mapped (``mode="replace"``).
    """
    new = _RENAMED.get((name, value)) if isinstance(value, str) else None
    if new is None:
        return value
    warnings.warn(f"{name} {value!r} is deprecated; use {new!r}", DeprecationWarning,
                  stacklevel=outside_the_package())  # the caller's own line
    return new


def check_number(value: Any, name: str, lo: float, hi: float = math.inf) -> float:
    """Return ``value`` as a float when it is a finite real number in ``[lo, hi]``."""
    real = not isinstance(value, bool) and isinstance(value, numbers.Real)
    if not (real and math.isfinite(value) and lo <= value <= hi):
        bound = f">= {lo:g}" if hi == math.inf else f"in [{lo:g}, {hi:g}]"
        raise OptionError(name, f"must be a finite number {bound}; got {value!r}")
    return float(value)


def _landmarks(value: Any) -> np.ndarray | None:
    """(p, 2) int64 pairs, each given once in order; a vertex paired twice is refused."""
    if value is None:
        return None
    lm = np.asarray(value)
    if lm.ndim == 2 and lm.dtype.kind == "f" and lm.size:  # np.loadtxt's default: whole numbers
        whole = np.isfinite(lm) & (lm == np.round(lm))
        if not whole.all():
            bad = float(lm[~whole][0])
            raise OptionError("landmarks", f": vertex indices must be whole numbers; got {bad!r}")
        lm = lm.astype(np.int64)
    if lm.ndim != 2 or lm.shape[1] != 2 or lm.shape[0] == 0 or lm.dtype.kind not in "iu":
        raise OptionError("landmarks", "must be a (p, 2) integer array of (source, target) vertex "
                          f"pairs; got {lm.dtype}{lm.shape}")  # fmt: skip
    if lm.min() < 0:
        raise OptionError("landmarks", f": vertex indices must be >= 0; got {lm.min()}")
    first = np.sort(np.unique(lm.astype(np.int64), axis=0, return_index=True)[1])
    pairs = lm[first].astype(np.int64)  # a pair given twice counts once
    for col, side, other in ((0, "source", "target"), (1, "target", "source")):
        values, counts = np.unique(pairs[:, col], return_counts=True)
        if np.any(counts > 1):
            v = int(values[np.argmax(counts > 1)])
            partners = sorted(int(x) for x in pairs[pairs[:, col] == v, 1 - col])
            raise OptionError("landmarks", f": {side} vertex {v} is paired with several {other} "
                              f"vertices ({', '.join(map(str, partners))}): give one pair per "
                              "vertex")  # fmt: skip
    pairs.setflags(write=False)
    return pairs


def same_frame_conflict(*, partial: bool, landmarks: bool, shells: bool) -> Said | None:
    """Return why ``same_frame`` cannot act beside these options, or None when it can.

    ``same_frame`` chooses among the shells' registrations, which only a full match without
    landmarks makes, ``shells`` on: with any of these options it would do nothing, so it is
    refused (by :class:`MatchOptions`, and by the command line before it reads anything).

    Parameters
    ----------
    partial : bool
        A partial match.
    landmarks : bool
        Landmarks are given.
    shells : bool
        The shells may be registered.

    Returns
    -------
    Said or None
        The reason, worded after the option's name.
    """
    if partial:
        why = "a partial match ({partial}) registers none"
    elif landmarks:
        why = "a match with landmarks registers none (the landmarks set its orientation)"
    elif not shells:
        why = "{no_shells} turns them off"
    else:
        return None
    return Said("chooses among the registrations of the shapes' smooth shells, and " + why
                + ": drop one of the two", {})  # fmt: skip


@dataclasses.dataclass(frozen=True, eq=False)
class MatchOptions:
    """How a map between two shapes is made (see :func:`o3d_ofp.match`).

    Attributes
    ----------
    method : {"estimate", "closest"}
        The spectral map, or closest points for shapes already in the same place.
    partial : bool
        The target is a part of the source, in the same units (estimate only).
    align : bool
        Rigid ICP pre-alignment before closest points (closest only).
    landmarks : (p, 2) ndarray of int or None
        Known (source, target) vertex pairs (estimate only; whole numbers as floats, as
        ``np.loadtxt`` reads them, are taken); each pair kept once, and kept exactly by the
        estimated map.
    components : {"auto", "largest", "error"}
        Policy for several connected components of the eigenbases computed.
    k_fit : int
        Size of the map fitted to the descriptors (the paper's K = 30 is 29).
    zoomout_to : int
        Eigenfunctions ZoomOut refines to (at least ``k_fit``).
    zoomout_subsample : int or None
        Farthest-point samples per shape for ZoomOut's iterations (None: every vertex).
    descriptors : {"wks", "hks"}
        Descriptor family ("wks" only for a partial match).
    w_orient : float
        Weight of the orientation-preserving term (>= 0).
    shells : bool
        When a full match between two meshes without landmarks comes out suspect, also
        register the shapes' smooth shells and keep the map that changes geodesic distances
        less (``o3d_ofp.core.shells.shell_match``; about 6 s more for such a pair of 5k
        vertices); a suspect partial match between meshes without landmarks registers the
        part onto the whole the same way (``o3d_ofp.core.shells.part_maps``; 3-5 s). False
        keeps the spectral map (estimate only).
    same_frame : bool
        The shapes are given in one frame (upright and facing the same way, as a scene or a
        dataset holds them): where the shells' registration fits front and back swapped about
        as well as the right way round, keep the registration that keeps that frame
        (``o3d_ofp.core.shells.SWAP_TURN``). Off by default: shapes in frames of their own (scans
        facing other ways) would be misled by it; the report of a registered map says when it
        would have chosen otherwise (estimate only).
    """

    method: str = "estimate"
    partial: bool = False
    align: bool = False
    landmarks: Any = None
    components: str = "auto"
    k_fit: int = FIT_K
    zoomout_to: int = ESTIMATION_K
    zoomout_subsample: int | None = 2000
    descriptors: str = "wks"
    w_orient: float = 1.0
    shells: bool = True
    same_frame: bool = False

    def __post_init__(self) -> None:
        check_choice(self.method, "method", ("estimate", "closest"))
        check_bool(self.partial, "partial")
        check_bool(self.align, "align")
        check_choice(self.components, "components", COMPONENTS)
        object.__setattr__(self, "landmarks", _landmarks(self.landmarks))
        check_int(self.k_fit, name="k_fit", minimum=1)
        check_int(self.zoomout_to, name="zoomout_to", minimum=1)
        if self.zoomout_to < self.k_fit:
            raise OptionError("zoomout_to", f"({self.zoomout_to}) must be >= k_fit ({self.k_fit}): "
                              "ZoomOut refines the fitted map to more eigenfunctions")  # fmt: skip
        sub = self.zoomout_subsample
        if sub is not None and (isinstance(sub, bool) or not isinstance(sub, numbers.Integral)
                                or sub < 2):  # fmt: skip
            raise OptionError("zoomout_subsample", f"must be None or an integer >= 2; got {sub!r}")
        check_choice(self.descriptors, "descriptors", ("wks",) if self.partial else ("wks", "hks"))
        check_number(self.w_orient, "w_orient", 0.0)
        check_bool(self.shells, "shells")
        check_bool(self.same_frame, "same_frame")
        closest = self.method == "closest"
        conflict = same_frame_conflict(partial=self.partial, landmarks=self.landmarks is not None,
                                       shells=self.shells)  # fmt: skip
        if self.same_frame and not closest and conflict is not None:
            raise OptionError("same_frame", conflict)
        for name, wrong in (
            ("partial", self.partial and closest),
            ("landmarks", self.landmarks is not None and closest),
            ("align", self.align and not closest),
            ("shells", not self.shells and closest),
            ("same_frame", self.same_frame and closest),
        ):
            if wrong:
                applies = "{closest}" if name == "align" else "{estimate}"
                raise OptionError(name, Said(f"applies to {applies}; method is {{method!r}}",
                                             {"method": self.method}))  # fmt: skip

    @property
    def estimation(self) -> dict[str, Any]:
        """The keyword options of the estimation itself (fit sizes, ZoomOut, descriptors)."""
        return {
            "k_fit": self.k_fit,
            "zoomout_to": self.zoomout_to,
            "zoomout_subsample": self.zoomout_subsample,
            "descriptors": self.descriptors,
            "w_orient": self.w_orient,
            "shells": self.shells,
            "same_frame": self.same_frame,
        }

    def landmarks_for(self, n_source: int, n_target: int) -> np.ndarray | None:
        """Return the landmarks, checked to lie within shapes of these vertex counts."""
        lm = self.landmarks
        for col, (n, side) in enumerate(((n_source, "source"), (n_target, "target"))):
            if lm is not None and lm[:, col].max() >= n:
                row = int(np.argmax(lm[:, col] >= n))
                raise OptionError("landmarks", f": {side} vertex indices must lie in [0, {n}); got "
                                  f"{lm[row, col]} in the pair {lm[row].tolist()} (1-based "
                                  "indices? they count from 0)")  # fmt: skip
        return lm


@dataclasses.dataclass(frozen=True)
class BasisOptions:
    """The OFP bases of a transfer (see :func:`o3d_ofp.ofp_basis`).

    Attributes
    ----------
    k1, k2 : int
        Eigenfunctions multiplied on the source and the target (the paper's K = 30 / 40 for
        humans; order 3 with k of 11-14 suits other shapes).
    order : int
        Product order.
    preset, tol
        Orthogonalization threshold ("ours" = 1e-2, "ours*" = 1e-9, or ``tol`` in (0, 1));
        both None: the task's default ("ours" for colors, "ours*" for transferred coordinates).
    matrix : {"p2p", "analytic"}
        How the transfer matrix is computed (see :func:`o3d_ofp.transfer_matrix`; "analytic"
        needs a functional map).
    """

    k1: int = DEFAULT_K
    k2: int = 39
    order: int = 2
    preset: str | None = None
    tol: float | None = None
    matrix: str = "p2p"

    def __post_init__(self) -> None:
        for name in ("k1", "k2", "order"):
            check_int(getattr(self, name), name=name, minimum=1)
        resolve_tol(self.tol, self.preset)
        check_choice(self.matrix, "matrix", ("p2p", "analytic"))

    def threshold(self, default: str = "ours") -> float:
        """Return the drop threshold: ``tol``, else ``preset``, else the ``default`` preset."""
        return resolve_tol(self.tol, self.preset if self.preset or self.tol else default)


@dataclasses.dataclass(frozen=True)
class DetailOptions:
    """A detail transfer (see :func:`o3d_ofp.transfer_detail`).

    Attributes
    ----------
    mode : {"add", "replace-detail", "coordinates"}
        "replace" is the deprecated name of "coordinates" (a DeprecationWarning).
    band : int or None
        None (the default): the detail is what the target lacks, calibrated on the two
        shapes (:func:`o3d_ofp.workflows.detail.calibrate_detail`). An int: the detail is
        what the coordinates have above this many eigenfunctions, whatever the target has
        (an expert's override; on a sphere choose a count that ends an eigenspace: 3, 8,
        15, 24, 35, ...).
    amount : float
        Multiplies the transferred detail, in [0, 10] (``o3d_ofp.workflows.options.MAX_AMOUNT``).
    """

    mode: str = "add"
    band: int | None = None
    amount: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", deprecated_choice("mode", self.mode))
        check_choice(self.mode, "mode", DETAIL_MODES)
        if self.band is not None:
            object.__setattr__(self, "band", check_int(self.band, name="band", minimum=1))
        object.__setattr__(self, "amount", check_number(self.amount, "amount", 0.0, MAX_AMOUNT))
