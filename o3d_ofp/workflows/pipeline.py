"""End-to-end transfer between two shapes, on arrays: map, bases, transfer matrix, signal.

The Open3D-level functions (:func:`o3d_ofp.transfer_colors`, :func:`o3d_ofp.transfer_detail`)
call these; the detail transfer itself is :mod:`o3d_ofp.workflows.detail`.

Defaults follow the paper: order 2 with k₁ = 29, k₂ = 39 non-constant eigenfunctions (its
K = 30 / 40, for humans); order 3 with k ≈ 11-14 suits other shapes (Tables 2, 5, 6).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from ..core._threads import PARALLEL_ROWS
from ..core._validation import as_signal, check_int
from ..core._warnings import warn
from ..core.basis import OFPBasis, check_basis_options, ofp_basis
from ..core.correspondence import check_fmap, check_p2p, p2p_from_fmap
from ..core.spectrum import EigenBasis
from ..core.transfer import transfer_matrix, transfer_signal
from .eigenbases import eigenbases as eigenbases_of
from .matching import (
    ESTIMATION_K,
    Correspondence,
    check_correspondence,
    check_landmarks,
    given_map_collapse,
    match_arrays,
    match_eigenbases,
    required_k,
    same_shape,
    uses_dense_path,
)
from .partial import check_partial_areas, match_partial_arrays, match_partial_eigenbases

__all__ = [
    "BasesAhead",
    "check_method",
    "check_partial_transfer",
    "estimate_for_transfer",
    "estimate_map",
    "estimate_map_arrays",
    "prepare_transfer",
    "pull_back",
    "transfer_function",
    "transfer_on_shapes",
    "warn_other_shape",
]

logger = logging.getLogger(__name__)


def _bases(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    k1: int,
    k2: int,
    order: int,
    tol: float | None,
    preset: str | None,
) -> tuple[OFPBasis, OFPBasis]:
    k1 = check_int(k1, name="k1", minimum=1, maximum=eig_1.k)
    k2 = check_int(k2, name="k2", minimum=1, maximum=eig_2.k)
    if max(eig_1.n_vertices, eig_2.n_vertices) >= PARALLEL_ROWS:  # BLAS on both cores already
        return (
            ofp_basis(eig_1, order=order, tol=tol, preset=preset, k=k1),
            ofp_basis(eig_2, order=order, tol=tol, preset=preset, k=k2),
        )
    # Smaller bases run their BLAS on one thread: one basis per core (27.5k vertices: 1.5 s
    # instead of 1.8 s for k1 = 29, k2 = 39).
    with ThreadPoolExecutor(max_workers=2) as pool:
        job = pool.submit(ofp_basis, eig_2, order=order, tol=tol, preset=preset, k=k2)
        return ofp_basis(eig_1, order=order, tol=tol, preset=preset, k=k1), job.result()


def check_method(method: Any) -> None:
    """Refuse an unknown transfer-matrix method (see :func:`transfer_function`)."""
    if method not in ("p2p", "analytic"):
        hint = ""
        if method in ("closest", "estimate"):  # match()'s methods, not the transfer's
            hint = (
                f" ({method!r} is a way to make the map: "
                f"o3d_ofp.match(source, target, method={method!r}"
                + (", align=True for almost aligned shapes" if method == "closest" else "")
                + "), then pass it as correspondence=)"
            )
        raise ValueError(
            f"method selects the transfer matrix, 'p2p' or 'analytic'; got {method!r}{hint}"
        )


class BasesAhead:
    """The OFP bases of a transfer, the target's built while the map is estimated.

    The estimation on the eigenbases leaves a core idle in its single-threaded stages (ZoomOut
    to ~100 eigenfunctions, the full-resolution point map). Given to
    :func:`prepare_transfer` as ``ready``, :meth:`start` begins the target's basis (the larger:
    k2 >= k1 by default) in a thread as soon as the eigenbases exist; :meth:`result` builds the
    source's here beside the end of it. Without a call to :meth:`start` (a given map, the
    dense path, shapes of :data:`~o3d_ofp.core._threads.PARALLEL_ROWS` vertices whose bases use
    both cores already) :meth:`result` builds both as :func:`transfer_function` does. The
    options are checked on construction, before any eigensolve.

    Use as a context manager: on an error the thread's basis is abandoned (its thread ends
    with it). With ``given`` bases nothing is checked or built: :meth:`result` returns them.
    """

    def __init__(
        self,
        k1: int,
        k2: int,
        *,
        order: int,
        tol: float | None,
        preset: str | None,
        given: tuple[OFPBasis, OFPBasis] | None = None,
    ) -> None:
        if given is None:
            check_basis_options(order, tol, preset)
        self._given = given
        self._k = (k1, k2)
        self._options: dict[str, Any] = {"order": order, "tol": tol, "preset": preset}
        self._pool: ThreadPoolExecutor | None = None
        self._target: Future[OFPBasis] | None = None

    def __enter__(self) -> BasesAhead:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=exc[0] is None, cancel_futures=True)

    def start(self, eig_1: EigenBasis, eig_2: EigenBasis) -> None:
        """Check the sizes against the eigenbases and start the target's basis."""
        if self._given is not None:
            return
        check_int(self._k[0], name="k1", minimum=1, maximum=eig_1.k)
        k2 = check_int(self._k[1], name="k2", minimum=1, maximum=eig_2.k)
        if max(eig_1.n_vertices, eig_2.n_vertices) >= PARALLEL_ROWS or self._pool is not None:
            return
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="o3d_ofp-basis")
        self._target = self._pool.submit(ofp_basis, eig_2, k=k2, **self._options)

    def result(self, eig_1: EigenBasis, eig_2: EigenBasis) -> tuple[OFPBasis, OFPBasis]:
        """Return the bases (B_1, B_2) of ``eig_1`` and ``eig_2`` (those given to ``start``)."""
        if self._given is not None:
            return self._given
        k1, k2 = self._k
        if self._target is None:
            opts = self._options
            return _bases(eig_1, eig_2, k1, k2, opts["order"], opts["tol"], opts["preset"])
        B_1 = ofp_basis(eig_1, k=k1, **self._options)
        return B_1, self._target.result()


def transfer_function(
    f_1: Any,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k1: int = 29,
    k2: int = 39,
    order: int = 2,
    tol: float | None = None,
    preset: str | None = None,
    correspondence: Correspondence | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    method: str = "p2p",
    bases: tuple[OFPBasis, OFPBasis] | None = None,
) -> np.ndarray:
    """Transfer a per-vertex signal from a source to a target shape with OFP bases.

    Parameters
    ----------
    f_1 : (n1,) or (n1, d) array_like of float
        Source signal.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases (with at least ``k1`` / ``k2`` eigenfunctions; more are
        used by ZoomOut when the map is estimated).
    k1, k2 : int, default 29, 39
        Eigenfunctions multiplied on each side.
    order : int, default 2
        Product order.
    tol, preset
        Orthogonalization threshold (default "ours", 1e-2); see :func:`o3d_ofp.ofp_basis`.
    correspondence : Correspondence, optional
        A map from :func:`o3d_ofp.match` (or :meth:`Correspondence.load`); its point map is
        used.
    fmap_12 : array_like, optional
        A functional map (at least (k2+1, k1+1)); its nearest-neighbour p2p map is used.
    p2p_21 : (n2,) array_like of int, optional
        A point-to-point map (target vertex → source vertex), used directly.
    landmarks : (p, 2) array_like of int, optional
        Known pairs, when the map is estimated.
    method : {"p2p", "analytic"}, default "p2p"
        How the transfer matrix is computed (see :func:`o3d_ofp.transfer_matrix`).
    bases : (OFPBasis, OFPBasis), optional
        Precomputed bases (then ``k1``, ``k2``, ``order``, ``tol`` and ``preset`` are unused).

    Returns
    -------
    (n2,) or (n2, d) ndarray
        The transferred signal.
    """
    check_method(method)
    for eig, name in ((eig_1, "eig_1"), (eig_2, "eig_2")):
        if not isinstance(eig, EigenBasis):  # a mesh given here: where its basis comes from
            raise TypeError(
                f"{name} must be an EigenBasis (from o3d_ofp.eigenbasis(mesh)); got "
                f"{type(eig).__name__} (for the colors of Open3D geometries, "
                "o3d_ofp.transfer_colors)"
            )
    f = as_signal(f_1, eig_1.n_vertices, name="f_1")
    B_1, B_2 = bases if bases is not None else _bases(eig_1, eig_2, k1, k2, order, tol, preset)
    if sum(x is not None for x in (correspondence, p2p_21, fmap_12)) > 1:
        raise ValueError("give at most one of correspondence, p2p_21 and fmap_12")
    if check_correspondence(correspondence) is not None:
        correspondence.check(
            eig_1.n_vertices, eig_2.n_vertices, source=eig_1.vertices, target=eig_2.vertices
        )
        p2p = correspondence.p2p_21
        if correspondence.quality is None:  # given, not estimated: nothing judged it yet
            _warn_collapse(p2p, eig_1.n_vertices, eig_2.n_vertices)
    elif p2p_21 is not None:
        p2p = check_p2p(p2p_21, eig_2.n_vertices, eig_1.n_vertices)
        _warn_collapse(p2p, eig_1.n_vertices, eig_2.n_vertices)
    elif fmap_12 is not None:
        C = np.asarray(fmap_12, dtype=np.float64)
        check_fmap(C, B_2.k + 1, B_1.k + 1)
        p2p = p2p_from_fmap(C, eig_1, eig_2)
    else:
        p2p = match_eigenbases(eig_1, eig_2, landmarks=landmarks).p2p_21
    if method == "analytic":
        if fmap_12 is None:
            raise ValueError("method='analytic' needs fmap_12")
        transfer_12 = transfer_matrix(B_1, B_2, fmap_12, method="analytic")
    else:
        transfer_12 = transfer_matrix(B_1, B_2, method="p2p", p2p_21=p2p)
    return transfer_signal(f, B_1, B_2, transfer_12)


def transfer_on_shapes(
    f_1: Any,
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
    *,
    k1: int,
    k2: int,
    order: int,
    tol: float | None,
    preset: str | None,
    method: str = "p2p",
    correspondence: Correspondence | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    eigenbases: tuple[Any, Any] | None = None,
    bases: tuple[Any, Any] | None = None,
    components: str = "auto",
    partial: bool = False,
) -> np.ndarray:
    """Prepare a transfer and carry ``f_1`` through it: the one-call route of the API.

    :func:`prepare_transfer`, then :func:`transfer_function`, the target's basis built while
    the map is estimated (see :class:`BasesAhead`). ``f_1`` is the (n1,) or (n1, d) source
    signal, or a callable giving it from the source's eigenbasis; the other arguments are
    those of the two functions. Returns the transferred (n2,) or (n2, d) signal.
    """
    check_method(method)
    with BasesAhead(k1, k2, order=order, tol=tol, preset=preset, given=bases) as ahead:
        eig_1, eig_2, correspondence = prepare_transfer(
            V1,
            F1,
            V2,
            F2,
            k1=k1,
            k2=k2,
            correspondence=correspondence,
            fmap_12=fmap_12,
            p2p_21=p2p_21,
            landmarks=landmarks,
            eigenbases=eigenbases,
            bases=bases,
            components=components,
            partial=partial,
            ready=ahead.start,
        )
        return transfer_function(
            f_1(eig_1) if callable(f_1) else f_1,
            eig_1,
            eig_2,
            correspondence=correspondence,
            fmap_12=fmap_12,
            p2p_21=p2p_21,
            method=method,
            bases=ahead.result(eig_1, eig_2),
        )


def _warn_collapse(p2p_21: np.ndarray, n_source: int, n_target: int) -> None:
    """Warn when a map given by the caller collapses (a trial's all-zero map, unsaid)."""
    why = given_map_collapse(p2p_21, n_source, n_target)
    if why is not None:
        warn(logger, f"the given map is doubtful: {why}")


def prepare_transfer(
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
    *,
    k1: int,
    k2: int,
    correspondence: Correspondence | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    eigenbases: tuple[Any, Any] | None = None,
    bases: tuple[Any, Any] | None = None,
    components: str = "auto",
    partial: bool = False,
    ready: Callable[[EigenBasis, EigenBasis], None] | None = None,
) -> tuple[EigenBasis, EigenBasis, Correspondence | None]:
    """Decide the eigenbases and the map of a transfer (the one place that does).

    Nothing given: :func:`estimate_for_transfer` (the cheaper route, dense path on large
    meshes). Eigenbases or bases given without a map: they are checked (or computed from the
    bases' size) and the map is estimated on them. A map given: eigenbases as large as it
    needs, the map passed through.

    Parameters
    ----------
    V1, F1 : (n1, 3) ndarray, (m1, 3) ndarray or None
        Source shape.
    V2, F2 : (n2, 3) ndarray, (m2, 3) ndarray or None
        Target shape.
    k1, k2 : int
        Eigenfunctions the transfer needs on each side.
    correspondence, fmap_12, p2p_21 : optional
        A known map (at most one).
    landmarks : (p, 2) array_like of int, optional
        Known (source, target) pairs for an estimated map.
    eigenbases : (EigenBasis, EigenBasis), optional
        Precomputed eigenbases (checked against the shapes).
    bases : (OFPBasis, OFPBasis), optional
        Precomputed OFP bases (their eigenbases are used when a map is given).
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components (see :func:`o3d_ofp.eigenbasis`).
    partial : bool, default False
        The target is a part of the source, in the same units: an estimated map is a partial
        one (:func:`o3d_ofp.workflows.partial.match_partial_eigenbases`, or
        :func:`~o3d_ofp.workflows.partial.match_partial_arrays` on the dense path). Refused
        with a given map (it is used as it is) and for a point cloud, before any eigensolve.
    ready : callable, optional
        ``ready(eig_1, eig_2)``, called when a map is estimated on full-resolution eigenbases,
        before the estimation (e.g. :meth:`BasesAhead.start`).

    Returns
    -------
    eig_1, eig_2 : EigenBasis
    correspondence : Correspondence or None
        The given or estimated map; None when ``fmap_12`` or ``p2p_21`` is given.
    """
    given = sum(x is not None for x in (correspondence, p2p_21, fmap_12))
    if given > 1:  # before any eigensolve
        raise ValueError("give at most one of correspondence, p2p_21 and fmap_12")
    # A map of the wrong size is refused before any eigensolve too (a trial's p2p_21 of 100
    # entries was refused after both eigenbases: minutes on a large scan); the shapes it was
    # made for are compared once, where it is used (transfer_function).
    if check_correspondence(correspondence) is not None:
        correspondence.check(V1.shape[0], V2.shape[0])
    if p2p_21 is not None:
        check_p2p(p2p_21, V2.shape[0], V1.shape[0])
    if bases is None:  # the OFP bases' sizes, named as the caller gave them
        k1 = check_int(k1, name="k1", minimum=1, maximum=max(1, V1.shape[0] - 2))
        k2 = check_int(k2, name="k2", minimum=1, maximum=max(1, V2.shape[0] - 2))
    known = given == 1
    check_partial_transfer(partial, known, V1, F1, V2, F2)
    if not known and eigenbases is None and bases is None:
        return estimate_for_transfer(
            V1,
            F1,
            V2,
            F2,
            k1=k1,
            k2=k2,
            landmarks=landmarks,
            components=components,
            partial=partial,
            ready=ready,
        )
    eig_1, eig_2 = _eigenbases(
        V1, F1, V2, F2, k1, k2, fmap_12, p2p_21, eigenbases, bases, correspondence, components
    )
    if not known:
        if ready is not None:
            ready(eig_1, eig_2)
        correspondence = estimate_map(eig_1, eig_2, partial=partial, landmarks=landmarks)
    return eig_1, eig_2, correspondence


def estimate_map(
    eig_1: EigenBasis, eig_2: EigenBasis, *, partial: bool = False, **options: Any
) -> Correspondence:
    """Estimate a map between two eigenbases: a partial one with ``partial``, else a full one.

    :func:`o3d_ofp.workflows.partial.match_partial_eigenbases` or
    :func:`o3d_ofp.workflows.matching.match_eigenbases`, ``options`` passed on.
    """
    return (match_partial_eigenbases if partial else match_eigenbases)(eig_1, eig_2, **options)


def estimate_map_arrays(
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
    *,
    partial: bool = False,
    **options: Any,
) -> Correspondence:
    """Estimate a map between two shapes' arrays (the dense path above its threshold).

    :func:`o3d_ofp.workflows.partial.match_partial_arrays` with ``partial``, else
    :func:`o3d_ofp.workflows.matching.match_arrays`, ``options`` passed on.
    """
    estimate = match_partial_arrays if partial else match_arrays
    return estimate(V1, F1, V2, F2, **options)


def check_partial_transfer(
    partial: bool,
    known: bool,
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
) -> None:
    """Refuse, before any eigensolve, a ``partial=`` that cannot apply to this transfer.

    ``partial`` must be a bool; True needs a map estimated here (``known`` False: a given map
    is used as it is), two triangle meshes and a target whose area can be a part of the
    source's (:func:`o3d_ofp.workflows.partial.check_partial_areas`).
    """
    if not isinstance(partial, bool):
        raise TypeError(f"partial must be True or False; got {partial!r}")
    if not partial:
        return
    if known:
        raise ValueError(
            "partial=True applies to a map estimated here; the given map (correspondence, "
            "p2p_21 or fmap_12) is used as it is: drop partial=True (a map from "
            "o3d_ofp.match(..., partial=True) is partial already)"
        )
    for F, name in ((F1, "source"), (F2, "target")):
        if F is None:
            raise ValueError(
                f"partial=True needs triangle meshes: the {name} is a point cloud (no faces); "
                "mesh it first or transfer without partial=True"
            )
    check_partial_areas(V1, F1, V2, F2)


def _eigenbases(
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
    k1: int,
    k2: int,
    fmap_12: Any,
    p2p_21: Any,
    eigenbases: tuple[Any, Any] | None,
    bases: tuple[Any, Any] | None,
    correspondence: Correspondence | None = None,
    components: str = "auto",
) -> tuple[Any, Any]:
    """Eigenbases for a transfer: given ones (checked), else those of the bases, else computed.

    Computed ones are as large as the map needs: a given map may be larger than k1/k2 (all of
    it is used); an estimated map is refined by ZoomOut to ~100 eigenfunctions (as in pyFM's
    standard pipeline), never more than a shape allows.
    """
    estimate = fmap_12 is None and p2p_21 is None and correspondence is None
    if eigenbases is None and bases is not None and not estimate:
        eigenbases = (bases[0].eig, bases[1].eig)  # no estimation: the bases' own suffice
    if eigenbases is None:
        if estimate:
            k1, k2 = max(k1, ESTIMATION_K), max(k2, ESTIMATION_K)
        elif fmap_12 is not None:
            rows, cols = np.shape(fmap_12)
            k1, k2 = max(k1, cols - 1), max(k2, rows - 1)
        eig_1, eig_2 = eigenbases_of(
            ((V1, F1, k1), (V2, F2, k2)),
            clamp_k=estimate,
            components=components,
            names=("the source", "the target"),
        )
        return eig_1, eig_2
    for eig, V, name in ((eigenbases[0], V1, "source"), (eigenbases[1], V2, "target")):
        if eig.n_vertices != V.shape[0]:
            raise ValueError(
                f"the {name} eigenbasis has {eig.n_vertices} vertices but the {name} has "
                f"{V.shape[0]}: it belongs to another shape"
            )
        warn_other_shape(eig, V, f"the {name} eigenbasis", f"the {name}")
    return eigenbases


def warn_other_shape(eig: EigenBasis, vertices: np.ndarray, what: str, shape: str) -> None:
    """Warn (OFPWarning) when ``eig`` was computed on another shape than ``vertices``.

    Same vertex count, other positions even up to a move, a rotation and a scaling: source
    and target swapped, or another pose of a shape with one triangulation (FAUST).
    """
    if not same_shape(eig.vertices, vertices):
        warn(
            logger,
            f"{what} was computed on another shape than {shape} (same vertex count, other "
            "positions even up to a move, a rotation or a scaling): source and target "
            "swapped, or another shape? It is used as it is",
        )


def estimate_for_transfer(
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
    *,
    k1: int,
    k2: int,
    landmarks: Any = None,
    components: str = "auto",
    partial: bool = False,
    progress: Any = None,
    ready: Callable[[EigenBasis, EigenBasis], None] | None = None,
) -> tuple[EigenBasis, EigenBasis, Correspondence]:
    """Compute the eigenbases of a transfer and estimate its map, by the cheaper route.

    Up to :data:`o3d_ofp.workflows.dense.DENSE_VERTICES` vertices, one eigensolve per shape of
    ~100 eigenfunctions serves the estimation and the bases (which use its leading
    ``k1``/``k2``). Above (two meshes), the map is estimated on coarse copies
    (:func:`o3d_ofp.workflows.matching.match_arrays`' dense path) and only ``k1``/``k2``
    eigenfunctions are computed at full resolution.

    Parameters
    ----------
    V1, F1 : (n1, 3) ndarray, (m1, 3) ndarray or None
        Source shape.
    V2, F2 : (n2, 3) ndarray, (m2, 3) ndarray or None
        Target shape.
    k1, k2 : int
        Eigenfunctions the transfer needs on each side.
    landmarks : (p, 2) array_like of int, optional
        Known (source, target) pairs (checked before any eigensolve).
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components (see :func:`o3d_ofp.eigenbasis`).
    partial : bool, default False
        The target is a part of the source (same units, two meshes: see
        :func:`check_partial_transfer`): the map is a partial one.
    progress : callable, optional
        ``progress(stage, fraction_done)`` of the map estimation.
    ready : callable, optional
        ``ready(eig_1, eig_2)``, called on the direct route with the eigenbases, before the map
        is estimated on them (e.g. :meth:`BasesAhead.start`); not on the dense one, whose
        full-resolution eigenbases come last.

    Returns
    -------
    eig_1, eig_2 : EigenBasis
        With at least ``k1`` / ``k2`` eigenfunctions.
    correspondence : Correspondence
        The estimated map (its quality logged by the estimation).
    """
    k1 = check_int(k1, name="k1", minimum=1)
    k2 = check_int(k2, name="k2", minimum=1)
    landmarks = check_landmarks(landmarks, V1.shape[0], V2.shape[0])
    check_partial_transfer(partial, False, V1, F1, V2, F2)
    meshes = F1 is not None and F2 is not None
    if uses_dense_path(V1.shape[0], V2.shape[0], meshes):
        corr = estimate_map_arrays(
            V1, F1, V2, F2, partial=partial, landmarks=landmarks, components=components,
            progress=progress,
        )  # fmt: skip
        eig_1, eig_2 = eigenbases_of(
            ((V1, F1, k1), (V2, F2, k2)), components=components, names=("the source", "the target")
        )
        return eig_1, eig_2, corr
    eig_1, eig_2 = eigenbases_of(
        [(V, F, max(k, required_k(V.shape[0]))) for V, F, k in ((V1, F1, k1), (V2, F2, k2))],
        clamp_k=True,
        components=components,
        names=("the source", "the target"),
    )
    if ready is not None:
        ready(eig_1, eig_2)
    corr = estimate_map(eig_1, eig_2, partial=partial, landmarks=landmarks, progress=progress)
    return eig_1, eig_2, corr


def pull_back(f_1: Any, correspondence: Correspondence, faces_1: Any = None) -> np.ndarray:
    """Carry a source signal to the target exactly through the map (no basis).

    With a surface map (``correspondence.barycentric_21``, e.g. ``match(method="closest")``)
    every target vertex gets the source signal interpolated at its point on the source
    surface; otherwise the value at its source vertex.

    Parameters
    ----------
    f_1 : (n1,) or (n1, d) array_like of float
        Source signal.
    correspondence : Correspondence
        The map.
    faces_1 : (m1, 3) array_like of int, optional
        The source triangles the surface map refers to (required with a surface map).

    Returns
    -------
    (n2,) or (n2, d) ndarray
    """
    correspondence = check_correspondence(correspondence)
    if correspondence is None:
        raise TypeError("pull_back needs a correspondence")
    f = as_signal(f_1, correspondence.n_source, name="f_1")
    if correspondence.barycentric_21 is None:
        return f[correspondence.p2p_21]
    if faces_1 is None:
        raise ValueError("a surface map needs the source triangles (faces_1)")
    F = np.asarray(faces_1)
    if F.ndim != 2 or F.shape[1] != 3 or correspondence.faces_21.max() >= F.shape[0]:
        raise ValueError(
            f"faces_1 has shape {F.shape}: not the triangles the correspondence refers to"
        )
    corners = F[correspondence.faces_21]  # (n2, 3) source vertices
    w = correspondence.barycentric_21
    if f.ndim == 1:
        return np.einsum("ij,ij->i", f[corners], w)
    return np.einsum("ijd,ij->id", f[corners], w)
