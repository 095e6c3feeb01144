"""What ``transfer`` and ``detail`` share: two shapes, a map (given, read or estimated)."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import logging
import os
import warnings
from typing import Any

import numpy as np

from ._common import (
    CLOUD_OUT,
    MESH_HELP,
    MESH_OUT,
    UsageError,
    about,
    add_basis_options,
    basis_for,
    check_basis_files_agree,
    eig_options,
    same_file,
    stage,
)
from ._types import positive_float, positive_int

__all__ = [
    "Pair",
    "add_pair_options",
    "estimate_or_use_map",
    "map_first",
    "read_pair",
]


logger = logging.getLogger(__name__)

#: Exit code of a suspect map under --strict (nothing is written).
SUSPECT_EXIT = 3


class SuspectMap(Exception):
    """The map is suspect and ``--strict`` was given."""


@dataclasses.dataclass
class Pair:
    """Two shapes and what the flags say about their map."""

    source: Any
    target: Any
    V1: np.ndarray
    F1: np.ndarray | None
    V2: np.ndarray
    F2: np.ndarray | None
    correspondence: Any  # Correspondence or None (estimate)
    landmarks: np.ndarray | None
    #: ``--target-scale``: ``target`` and ``V2`` are the file's scaled by it (None: as read)
    target_scale: float | None = None
    #: The target as read, before ``--target-scale`` (None: ``target`` is)
    target_as_read: Any = None

    @property
    def own_target(self) -> Any:
        """The target as read: results that keep its coordinates are made like it."""
        return self.target if self.target_as_read is None else self.target_as_read

    def in_target_units(self, geometry: Any) -> Any:
        """Return ``geometry``, made from the scaled target, in the target file's own units."""
        if self.target_scale is None:
            return geometry
        from ..boundary.convert import scaled_copy

        return scaled_copy(geometry, 1.0 / self.target_scale)


def add_pair_options(p: argparse.ArgumentParser, *, preset: str, several: bool = False) -> None:
    """Positional source/target(s) and the map, basis and landmark flags.

    With ``several``, ``target`` is a list (files and folders: see :mod:`._many`).
    """
    p.add_argument("source", help="source " + MESH_HELP)
    if several:
        p.add_argument(
            "target", nargs="+", help="target " + MESH_HELP + "; several, or a folder of them"
        )
    else:
        p.add_argument("target", help="target " + MESH_HELP)
    p.add_argument("--k1", type=positive_int, help="source eigenfunctions (29)")
    p.add_argument("--k2", type=positive_int, help="target eigenfunctions (39)")
    add_basis_options(p, k=None, preset=preset)
    p.add_argument(
        "--map",
        default="estimate",
        help="estimate (default: WKS fit + ZoomOut to 100), closest (closest points on the "
        "source surface, for shapes already aligned in space; --align for nearly aligned "
        "ones), identity (same vertices), MAP.npz "
        "(from --save-map), a file with one source vertex per target vertex (.vts 1-based / "
        ".npy 0-based), or SRC.vts,TGT.vts matching both shapes to a template",
    )
    p.add_argument(
        "--align", action="store_true", help="with --map closest: rigid ICP pre-alignment first"
    )
    p.add_argument(
        "--partial",
        action="store_true",
        help="with --map estimate: the target is a part of the source (a one-sided scan, a "
        "cut) in the same units (else --target-scale): partial functional maps; the report "
        "gives the overlap",
    )
    p.add_argument(
        "--target-scale",
        type=positive_float,
        metavar="FACTOR",
        help="one target: multiply its coordinates by FACTOR for the run (a target in other "
        "units than the source: 0.001 for millimetres onto metres), as if its file were in "
        "the source's units; the result is written in the target's own units",
    )
    p.add_argument("--save-map", metavar="MAP.npz", help="write the map used (to reuse: --map)")
    p.add_argument(
        "--strict",
        action="store_true",
        help="a suspect map (estimated, closest, or a map file that collapses) is an error "
        "(exit 3, nothing written)",
    )
    p.add_argument(
        "--landmarks",
        help="known (source, target) vertex pairs for the estimation, 0-based: 12:40,500:611 "
        "(or 12:40;500:611), "
        "a 2-column file (spaces, commas or semicolons apart), or 'pick' (pick them on both "
        "shapes in Open3D's vertex-selection window; needs a display)",
    )
    p.add_argument(
        "--save-landmarks",
        metavar="FILE",
        help="write the landmark pairs used (e.g. picked) as a 2-column file (to reuse: "
        "--landmarks FILE)",
    )
    p.add_argument("--basis-1", help="cached source basis (.npz from 'o3d-ofp basis')")
    p.add_argument("--basis-2", help="cached target basis (.npz from 'o3d-ofp basis')")


def _landmarks(spec: str | None, n1: int, n2: int) -> np.ndarray | None:
    if not spec:
        return None
    if os.path.isfile(spec):
        try:
            # utf-8-sig: a spreadsheet's "CSV UTF-8" starts with a byte-order mark
            with open(spec, encoding="utf-8-sig") as fh, warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "no data": said below
                pairs = np.loadtxt(  # whitespace, commas or semicolons (CSVs) apart
                    (line.replace(",", " ").replace(";", " ") for line in fh),
                    dtype=np.float64,
                    ndmin=2,
                )
        except (ValueError, UnicodeDecodeError) as exc:
            # numpy's message for a ragged file ends with advice for its own API ("; use
            # `usecols` to select a subset ..."): only what precedes it is about the file
            said = str(exc).split("; use `usecols`")[0]
            raise UsageError(
                f"--landmarks {spec}: not a text file of two integer columns (source vertex, "
                f"target vertex; '#' starts a comment): {said}"
            ) from exc
        if pairs.size and pairs.shape[1] != 2:
            raise UsageError(
                f"--landmarks {spec}: {pairs.shape[1]} column{'s' * (pairs.shape[1] > 1)}; the "
                "file needs two (source vertex, target vertex, 0-based) on each line"
            )
        if not pairs.size:
            raise UsageError(f"--landmarks {spec}: no pairs in the file")
    else:
        if ":" not in spec or os.sep in spec:
            raise UsageError(f"--landmarks {spec}: no such file (or give pairs like 12:40,500:611)")
        try:
            pairs = np.array(
                # commas or semicolons apart, as in a file
                [[float(x) for x in item.split(":")] for item in spec.replace(";", ",").split(",")],
                dtype=float,
            )
        except ValueError as exc:
            raise UsageError(
                f"--landmarks must be a file or pairs like 12:40,500:611; got {spec!r}"
            ) from exc
    if (
        pairs.ndim != 2
        or pairs.shape[1] != 2
        or not np.all(np.isfinite(pairs))
        or np.any(pairs != np.round(pairs))
    ):
        raise UsageError(
            f"--landmarks {spec}: the values must be integer vertex indices"
            if os.path.isfile(spec)
            else f"--landmarks must be integer (source, target) pairs; got {spec!r}"
        )
    pairs = pairs.astype(np.int64)
    for col, n, name in ((0, n1, "source"), (1, n2, "target")):
        if pairs[:, col].min() < 0 or pairs[:, col].max() >= n:
            where = f" {spec}" if os.path.isfile(spec) else ""
            raise UsageError(f"--landmarks{where}: {name} indices must lie in [0, {n}) (0-based)")
    from ..workflows.matching import check_landmarks

    try:
        return check_landmarks(pairs, n1, n2)
    except ValueError as exc:
        raise UsageError(f"--landmarks {spec}: {exc}") from exc


def _check_extra_output(args: argparse.Namespace, path: str, flag: str) -> None:
    """Refuse a ``--save-map`` / ``--save-landmarks`` file that would replace another file.

    That is an input of the command, the result, the other such file, or a cache entry.
    Found by a trial: ``--save-landmarks`` replaced the ``--signal`` file it was about to read,
    or was replaced by ``-o``; ``--save-map`` replaced a ``--basis-2`` file or a cache entry.
    """
    from ._common import written_beside

    inputs = [
        ("an input of this command", getattr(args, name, None))
        for name in ("source", "target", "signal", "texture", "landmarks", "basis_1", "basis_2")
    ]
    inputs += [("the --map file read", f) for f in getattr(args, "map", "").split(",")]
    output = getattr(args, "output", None)
    outputs = [("the -o output", output)]
    if output:
        from ._signal import signal_sides

        outputs += [("written with -o", f) for f in written_beside(output)]
        outputs += [("written with -o", f) for f in signal_sides(args)]  # a .npy signal's
    others = {"--save-map": "save_map", "--save-landmarks": "save_landmarks"}
    outputs += [(f"the {o} file", getattr(args, n, None)) for o, n in others.items() if o != flag]
    for what, other in (*inputs, *outputs):
        if isinstance(other, str) and other and same_file(path, other):
            raise UsageError(f"{flag} {path}: is {what}; it would be overwritten")
    cache = getattr(args, "cache", None)
    if cache and os.path.dirname(os.path.abspath(path)) == os.path.abspath(cache):
        raise UsageError(f"{flag} {path}: is in the --cache folder {cache}; choose another")


def _check_landmark_flags(args: argparse.Namespace) -> None:
    """Refuse ``--landmarks pick`` without a display, and a bad ``--save-landmarks``, early."""
    if args.landmarks == "":
        raise UsageError(
            "--landmarks is empty: give pairs like 12:40,500:611, a 2-column file or 'pick'"
        )
    save = getattr(args, "save_landmarks", None)
    if save:
        if not args.landmarks:
            raise UsageError("--save-landmarks needs --landmarks (pick, pairs or a file)")
        if os.path.isdir(save):
            raise UsageError(f"--save-landmarks {save}: is a directory")
        if not os.path.isdir(os.path.dirname(os.path.abspath(save))):
            raise UsageError(f"--save-landmarks {save}: the folder does not exist")
        _check_extra_output(args, save, "--save-landmarks")
    if args.landmarks != "pick":
        return
    from ..boundary.pick import has_display

    if args.map != "estimate":
        raise UsageError("--landmarks pick applies to --map estimate")
    if not has_display():
        raise UsageError(
            "--landmarks pick needs a display to open Open3D's picking window (DISPLAY and "
            "WAYLAND_DISPLAY are not set); give the pairs in a file instead: --landmarks FILE "
            "(two columns: source vertex, target vertex)"
        )


def _pick(source: Any, target: Any) -> np.ndarray:
    """Pick the landmark pairs in Open3D's window (``--landmarks pick``)."""
    from ..boundary.pick import pick_landmarks

    try:
        return pick_landmarks(source, target)
    except (ValueError, RuntimeError) as exc:
        raise UsageError(f"--landmarks pick: {exc}") from exc


def _read_map(spec: str, V1: np.ndarray, V2: np.ndarray) -> Any:
    """Read the Correspondence named by ``--map`` (None: estimate), checked for both shapes."""
    from ..core.correspondence import p2p_from_template
    from ..core.io import read_vts
    from ..workflows.matching import Correspondence

    n1, n2 = V1.shape[0], V2.shape[0]
    if spec in ("estimate", "closest"):
        return None
    if spec == "identity":
        if n1 != n2:
            copies = [
                f"{extra} of the {name}'s are copies at the same position as another (e.g. an "
                "OBJ's along its UV seams)"
                for name, V in (("source", V1), ("target", V2))
                if (extra := V.shape[0] - np.unique(V, axis=0).shape[0])
            ]
            raise UsageError(
                f"--map identity needs shapes with the same vertices; got {n1} and {n2}"
                + (f" ({'; '.join(copies)})" if copies else "")
                + ": --map closest maps shapes in the same place whatever their vertices"
            )
        return Correspondence(p2p_21=np.arange(n2), n_source=n1, method="identity")
    files = spec.split(",")
    for f in files:
        if not os.path.isfile(f):
            raise UsageError(
                f"--map {f}: no such map file (--map estimate|closest|identity|MAP.npz|FILE[,FILE])"
            )
    if len(files) == 2:  # correspondences of both shapes to a common template
        try:
            p2p = p2p_from_template(read_vts(files[0]), read_vts(files[1]), V2)
        except (ValueError, TypeError) as exc:
            raise UsageError(f"--map {spec}: {exc}") from exc
        if p2p.max() >= n1:
            raise UsageError(f"--map {files[0]}: source indices must lie in [1, {n1}] (1-based)")
        return Correspondence(p2p_21=p2p, n_source=n1, method="template")
    if len(files) != 1:
        raise UsageError(f"--map takes one file or two comma-separated .vts files; got {spec!r}")
    path = files[0]
    if path.endswith(".npz"):
        try:
            corr = Correspondence.load(path)
            corr.check(n1, n2, name=f"--map {path}")  # the shapes: _check_given_map
        except (ValueError, TypeError) as exc:
            raise UsageError(f"--map {exc}" if str(exc).startswith(path) else str(exc)) from exc
        return corr
    if path.endswith(".npy"):
        from ._common import load_npy

        p2p = load_npy(path, "0-based target->source map", flag="--map")
    else:
        if os.path.splitext(path)[1].lower() in (*MESH_OUT, *CLOUD_OUT):
            raise UsageError(
                f"--map {path}: a mesh or point-cloud file, not a map (--map estimate|closest|"
                "identity|MAP.npz|FILE.vts|FILE.npy|SRC.vts,TGT.vts); the shapes are the "
                "positional arguments"
            )
        try:
            p2p = read_vts(path)
        except ValueError as exc:
            raise UsageError(f"--map {exc}") from exc
    p2p = np.asarray(p2p)
    if p2p.shape != (n2,) or not np.issubdtype(p2p.dtype, np.integer):
        raise UsageError(
            f"--map {path}: a map file lists one source vertex per target vertex ({n2} "
            f"integers); got shape {p2p.shape} and dtype {p2p.dtype}"
        )
    if p2p.min() < 0 or p2p.max() >= n1:
        raise UsageError(
            f"--map {path}: source indices must lie in [0, {n1}) (1-based in .vts); got "
            f"[{p2p.min()}, {p2p.max()}]"
        )
    return Correspondence(p2p_21=p2p, n_source=n1, method="given")


def _check_components(
    args: argparse.Namespace, V1: np.ndarray, F1: Any, V2: np.ndarray, F2: Any
) -> None:
    """Refuse a shape the eigensolves would refuse (``--components``) before either runs.

    The shapes whose bases are computed (not read with ``--basis-1``/``--basis-2``), and not
    with ``--map closest``, which builds no basis before its map.
    """
    from ..workflows.eigenbases import check_shapes

    if args.map == "closest":
        return
    sides = [
        (path, (V, F))
        for path, V, F, file in (
            (args.source, V1, F1, args.basis_1),
            (args.target, V2, F2, args.basis_2),
        )
        if not file
    ]
    try:  # its messages begin with the name given: here the file's
        check_shapes(
            [shape for _, shape in sides],
            names=[path for path, _ in sides],
            components=getattr(args, "components", "auto"),
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from exc


def read_pair(args: argparse.Namespace) -> Pair:
    """Read both shapes, the map and the landmarks: everything that can fail fast."""
    from ._common import check_cache_dir, check_writable_folder, read_shape

    check_cache_dir(getattr(args, "cache", None))
    _check_landmark_flags(args)
    if args.save_map:
        if not args.save_map.endswith(".npz"):
            raise UsageError(f"--save-map {args.save_map}: must end with .npz")
        _check_extra_output(args, args.save_map, "--save-map")
        check_writable_folder(
            os.path.dirname(os.path.abspath(args.save_map)), args.save_map, flag="--save-map"
        )
    if args.align and args.map != "closest":
        raise UsageError("--align applies to --map closest")
    if getattr(args, "partial", False) and args.map != "estimate":
        raise UsageError(
            f"--partial applies to --map estimate (the partial match), not to --map {args.map}"
            + ("" if args.map in ("closest", "identity") else
               ", a map used as it is (a map saved from a run with --partial is partial "
               "already)")
            + ": drop --partial"
        )  # fmt: skip
    source, V1, F1 = read_shape(args.source)
    target, V2, F2 = read_shape(args.target)
    target_as_read, factor, V2_read = None, getattr(args, "target_scale", None), V2
    if factor is not None and getattr(args, "basis_2", None):
        raise UsageError(
            f"--basis-2 {args.basis_2} holds the basis of {args.target} in its own units, and "
            "--target-scale changes them: drop --basis-2 (--cache DIR keeps the scaled "
            "target's basis apart)"
        )
    if factor is not None:  # every step below sees the target in the source's units
        from ..boundary.convert import scaled_copy

        target_as_read, target, V2 = target, scaled_copy(target, factor), V2 * factor
    corr = _read_map(args.map, V1, V2)
    if corr is not None and args.map != "closest":
        _check_given_map(args, corr, V1, V2)
    if getattr(args, "partial", False):
        for F, path in ((F1, args.source), (F2, args.target)):
            if F is None:
                raise UsageError(
                    f"--partial needs triangle meshes: {path} is a point cloud (no faces); "
                    "mesh it first or match without --partial"
                )
        from ..workflows.partial import check_partial_areas

        scaled_name = args.target if factor is None else f"{args.target} scaled by {factor:g}"
        try:
            check_partial_areas(V1, F1, V2, F2, names=(args.source, scaled_name))
        except ValueError as exc:
            if factor is None:
                raise UsageError(str(exc)) from exc
            # the advice for the file as it is, whose factor is the one to give
            try:
                check_partial_areas(V1, F1, V2_read, F2, names=(args.source, args.target))
            except ValueError as own:
                said = f"--target-scale {factor:g} does not fix the units: {own}"
                raise UsageError(said) from exc
            raise UsageError(
                f"--target-scale {factor:g}: {exc}; {args.target} as it is would be admitted: "
                "drop --target-scale"
            ) from exc
    _check_components(args, V1, F1, V2, F2)
    if args.map == "closest" and args.landmarks:
        raise UsageError("--landmarks apply to --map estimate, not --map closest")
    if args.landmarks and corr is not None:
        raise UsageError("--landmarks only apply with --map estimate")
    if corr is None and args.map == "estimate" and not _dense(args, V1, F1, V2, F2):
        # the eigenbases of the estimation must fit (the dense path computes none of them)
        from ..workflows.matching import ESTIMATION_K, required_k
        from ._common import check_job_memory

        check_job_memory(
            [(p, V.shape[0], 1, required_k(V.shape[0], ESTIMATION_K), 1)
             for p, V in ((args.source, V1), (args.target, V2))],
            advice="the map estimation needs 99 eigenfunctions per shape: use simplified "
            "meshes (fewer vertices), or give the map with --map FILE",
        )  # fmt: skip
    if args.landmarks == "pick":
        landmarks = _pick(source, target)
    else:
        landmarks = _landmarks(args.landmarks, V1.shape[0], V2.shape[0])
    if landmarks is not None and getattr(args, "save_landmarks", None):
        from ..core._atomic import atomic_path

        with atomic_path(args.save_landmarks, suffix=".txt") as tmp:
            np.savetxt(tmp, landmarks, fmt="%d", header="source_vertex target_vertex (0-based)")
        from ._common import report

        report([f"wrote {landmarks.shape[0]} landmark pairs to {args.save_landmarks}"])
    return Pair(source, target, V1, F1, V2, F2, corr, landmarks, factor, target_as_read)


def bases_for_pair(args: argparse.Namespace, pair: Pair) -> tuple[Any, Any, Any, Any]:
    """(B1, B2, eig_1, eig_2): the OFP bases and the eigenbases the map needs."""
    from ..core._memory import basis_job_bytes
    from ..core.products import n_eigenproducts
    from ..core.spectrum import eigenbasis
    from ..workflows.eigenbases import answer_bytes, run_per_shape
    from ..workflows.matching import ESTIMATION_K, required_k
    from ._common import check_job_memory

    check_basis_files_agree(args)  # before either basis is made (a dense map comes first)
    estimate = pair.correspondence is None
    for side, path, V, k, file in ((1, args.source, pair.V1, args.k1, args.basis_1),
                                   (2, args.target, pair.V2, args.k2, args.basis_2)):  # fmt: skip
        if k is not None and not file and k > V.shape[0] - 2:  # before the memory estimate
            raise UsageError(
                f"--k{side} {k}: must be smaller than the number of vertices of {path} minus "
                f"one ({V.shape[0]} vertices: at most {V.shape[0] - 2})"
            )
    jobs = [
        (path, V.shape[0], k or default, required_k(V.shape[0], ESTIMATION_K) if estimate else 0,
         args.order)
        for path, V, k, default, file in (
            (args.source, pair.V1, args.k1, 29, args.basis_1),
            (args.target, pair.V2, args.k2, 39, args.basis_2),
        )
        if not file
    ]  # fmt: skip
    check_job_memory(
        jobs, advice="lower --k1/--k2 or --order, or use simplified meshes (fewer vertices)"
    )

    def side_job(side: int, k: Any, default: int, file: Any) -> tuple[Any, Any]:
        V, F = (pair.V1, pair.F1) if side == 1 else (pair.V2, pair.F2)
        path = args.source if side == 1 else args.target
        want = required_k(V.shape[0], ESTIMATION_K) if estimate else None
        with about(path):
            B, eig = basis_for(
                V,
                F,
                path,
                args,
                k=k,
                default_k=default,
                k_flag=f"--k{side}",
                eig_k=want,
                file=file,
                file_flag=f"--basis-{side}",
            )
            if estimate and eig.k < want:  # a basis file with fewer eigenfunctions
                with stage(f"eigenbasis of {path} for map estimation (k={want})"):
                    eig = eigenbasis(V, F, k=want, clamp_k=True, **eig_options(args))
        return B, eig

    sides = ((1, args.k1, 29, args.basis_1), (2, args.k2, 39, args.basis_2))
    # Both sides at once, one per core, when both are computed (a basis file is only read).
    vertices, memory = [], []
    for (_, k, default, file), V in zip(sides, (pair.V1, pair.V2), strict=True):
        n, k = V.shape[0], k or default
        eig_k = max(k, required_k(n, ESTIMATION_K)) if estimate else k
        vertices.append(0 if file else n)
        kept = min(n_eigenproducts(min(k, n - 1), args.order), n)  # at most, "ours" keeps fewer
        memory.append(
            basis_job_bytes(n, k=k, order=args.order, eig_k=eig_k)
            + answer_bytes(n, eig_k + 1 + kept)
        )
    out = run_per_shape(
        [functools.partial(side_job, *side) for side in sides],
        vertices,
        memory,
        what="bases of both shapes",
    )
    (B1, e1), (B2, e2) = out
    return B1, B2, e1, e2


def _dense(args: argparse.Namespace, V1: Any, F1: Any, V2: Any, F2: Any) -> bool:
    """Whether the estimated map of this pair takes the dense path (coarse meshes)."""
    from ..workflows.matching import uses_dense_path

    meshes = F1 is not None and F2 is not None
    return uses_dense_path(V1.shape[0], V2.shape[0], meshes)




def _check_given_map(args: argparse.Namespace, corr: Any, V1: np.ndarray, V2: np.ndarray) -> None:
    """Say when a map read from a file is doubtful; ``--strict`` makes that an error.

    A map file of the right length and range can still be garbage (another pair's map, a
    broken export): when fewer distinct source vertices than
    :data:`o3d_ofp.workflows.matching.GIVEN_MAP_COLLAPSE` of the smaller shape are hit, the
    result would be a few flat colors. A map saved by
    ``--save-map`` (.npz) also carries its quality, printed here, and the signatures of the
    shapes it was made for: a map saved suspect, or made for other shapes (source and target
    swapped, another pair with the same vertex counts), is doubtful too.
    """
    from ..workflows.matching import given_map_collapse
    from ._common import report

    n1, n2 = V1.shape[0], V2.shape[0]
    reasons = []
    collapse = given_map_collapse(corr.p2p_21, n1, n2)
    if collapse is not None:
        reasons.append(f"--map {args.map}: {collapse}")
    if args.map.endswith(".npz"):
        other = corr.mismatch(V1, V2, name=f"--map {args.map}")
        if other is not None:
            reasons.append(other)
        if corr.quality is not None:
            report([f"stored with --map {args.map}: {corr.quality.summary()}"])
            if corr.quality.suspect:
                reasons.append(
                    f"--map {args.map} was saved with a suspect quality: "
                    + "; ".join(corr.quality.reasons)
                )
    if not reasons:
        return
    if args.strict:
        raise SuspectMap("; ".join(reasons))
    for reason in reasons:
        logger.warning("%s", reason)
    report([f"map quality SUSPECT: {reason}" for reason in reasons])


def _report_quality(args: argparse.Namespace, corr: Any) -> None:
    """Print the quality of an estimated map; ``--strict`` turns a suspect one into an error."""
    from ._common import report

    report([corr.quality.summary(), *corr.quality.notes])
    if corr.quality.suspect and args.strict:
        raise SuspectMap("; ".join(corr.quality.reasons))


def _closest_map(args: argparse.Namespace, pair: Pair) -> Pair:
    """Return the pair with its closest-point map (``--map closest``), its quality printed."""
    from ..boundary.closest import closest_correspondence

    with stage("closest points on the source surface"):
        try:
            corr = closest_correspondence(
                pair.V1, pair.F1, pair.V2, faces_2=pair.F2, align=args.align
            )
        except ValueError as exc:
            raise UsageError(f"--map closest: {exc}") from exc
    _report_quality(args, corr)
    return dataclasses.replace(pair, correspondence=corr)


def map_first(args: argparse.Namespace, pair: Pair) -> Pair:
    """Compute the maps that need no basis: closest points, or the dense path's estimate.

    Called once the inputs (and the signal) have been read and checked, so that a bad input
    is refused before this work. Returns the pair with its map for ``--map closest`` and for
    two large meshes (estimated on coarse copies, no full-size eigenbasis), the pair
    unchanged otherwise (the map is then estimated from the eigenbases the bases are built
    from).
    """
    if pair.correspondence is None and args.map == "closest":
        return _closest_map(args, pair)
    if pair.correspondence is not None or args.map != "estimate":
        return pair
    if not _dense(args, pair.V1, pair.F1, pair.V2, pair.F2):
        return pair
    from ..workflows.matching import match_arrays
    from ._progress import stage_progress

    n = max(pair.V1.shape[0], pair.V2.shape[0])
    with (
        stage(f"map estimation on coarse copies ({n} vertices: dense path)"),
        stage_progress("matching") as progress,
    ):
        match = match_arrays
        if getattr(args, "partial", False):
            from ..workflows.partial import match_partial_arrays as match
        corr = match(
            pair.V1,
            pair.F1,
            pair.V2,
            pair.F2,
            landmarks=pair.landmarks,
            progress=progress,
            **eig_options(args),
        )
    _report_quality(args, corr)
    return dataclasses.replace(pair, correspondence=corr)


def estimate_or_use_map(args: argparse.Namespace, pair: Pair, eig_1: Any, eig_2: Any) -> Any:
    """Return the pair's map: the given one, or estimated (quality printed, --strict)."""
    from ..workflows.matching import match_eigenbases
    from ._common import report
    from ._progress import stage_progress

    corr = pair.correspondence
    if corr is None:
        partial = getattr(args, "partial", False)
        what = (
            "partial map estimation (descriptor fits, partial ZoomOut, geodesic refinement, "
            "checks)" if partial else "map estimation (descriptor fit, ZoomOut, point map)"
        )  # fmt: skip
        with stage(what), stage_progress("matching") as progress:
            match = match_eigenbases
            if partial:
                from ..workflows.partial import match_partial_eigenbases as match
            corr = match(eig_1, eig_2, landmarks=pair.landmarks, progress=progress)
        _report_quality(args, corr)
    if args.save_map:
        corr.save(args.save_map)
        report([f"wrote the map to {args.save_map}"])
    return corr
