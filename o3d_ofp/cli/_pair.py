"""What ``transfer`` and ``detail`` share: two shapes, their map, the plan and its run.

The flags become the library's options (:class:`~o3d_ofp.MatchOptions`,
:class:`~o3d_ofp.BasisOptions`); :func:`o3d_ofp.workflows.plan.plan_pair` decides what the job
computes (how the map is made, the eigenbasis sizes, the dense path, the bases) and
:func:`o3d_ofp.workflows.plan.prepare` runs it. What is read here is checked before it.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import itertools
import logging
import os
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from ..boundary.api import match
from ..boundary.convert import scaled_copy
from ..boundary.pick import has_display, pick_landmarks
from ..core._atomic import atomic_path
from ..core._rows import unique_rows
from ..core.correspondence import p2p_from_template
from ..core.io import read_vts
from ..core.wording import AdvisedError, Said
from ..workflows.maps import (
    Correspondence,
    given_map_collapse,
    template_misfit,
    with_signatures,
)
from ..workflows.options import BasisOptions, MatchOptions, same_frame_conflict
from ..workflows.partial import check_partial_areas
from ..workflows.plan import Plan, Prepared, plan_pair, prepare
from . import _common as common
from ._common import UsageError, positive_float, positive_int, report, stage
from ._progress import stage_progress

logger = logging.getLogger(__name__)

#: Exit code of a suspect map under --strict (nothing is written).
SUSPECT_EXIT = 3
#: How the stage line names the estimation of each estimator.
_ESTIMATION = {"full": "map estimation (descriptor fit, ZoomOut, point map)", "partial": "partial "
               "map estimation (descriptor fits, partial ZoomOut, geodesic refinement, checks)"}


class SuspectMap(Exception):
    """The map is suspect and ``--strict`` was given."""


@dataclasses.dataclass
class Pair:
    """Two shapes, the map the flags give (None: made by the plan) and the match options."""

    source: Any
    target: Any
    V1: np.ndarray
    F1: np.ndarray | None
    V2: np.ndarray
    F2: np.ndarray | None
    given: Correspondence | None
    match: MatchOptions
    names: tuple[str, str]
    #: The target as read: results that keep its coordinates are made like it
    own_target: Any
    #: ``--target-scale``: ``target`` and ``V2`` are the file's scaled by it (None: as read)
    target_scale: float | None = None
    #: ``--basis-1`` / ``--basis-2``: the OFP bases read, once the plan uses them
    files: tuple[Any, ...] = (None, None)
    #: The flag values the command reads files from (those that are not files are skipped)
    inputs: tuple[str | None, ...] = ()

    def in_target_units(self, geometry: Any) -> Any:
        """Return ``geometry``, made from the scaled target, in the target file's own units."""
        scale = self.target_scale
        return geometry if scale is None else scaled_copy(geometry, 1.0 / scale)


def add_pair_options(p: argparse.ArgumentParser, *, preset: str, several: bool = False) -> None:
    """Positional source/target(s) and the map, basis and landmark flags.

    With ``several``, ``target`` is a list (files and folders: see :func:`._common.run_transfers`).
    """
    default, a = BasisOptions(), p.add_argument
    a("source", help="source " + common.MESH_HELP)
    a("target", nargs="+" if several else None,
      help="target " + common.MESH_HELP + ("; several, or a folder of them" if several else ""))
    a("--k1", type=positive_int, help=f"source eigenfunctions ({default.k1})")
    a("--k2", type=positive_int, help=f"target eigenfunctions ({default.k2})")
    common.add_basis_options(p, k=False, preset=preset)
    a("--map", default="estimate", help="estimate (default: WKS fit + ZoomOut), closest (closest "
      "points on the source surface: shapes aligned in space; --align: nearly aligned), identity "
      "(same vertices), MAP.npz (--save-map), one source vertex per target vertex (FILE.vts "
      "1-based, FILE.npy 0-based), or SRC.vts,TGT.vts (both shapes' template matches)")
    a("--align", action="store_true", help="with --map closest: rigid ICP pre-alignment first")
    a("--partial", action="store_true", help="with --map estimate: the target is a part of the "
      "source (a scan, a cut) in its units (else --target-scale); the report gives the overlap")
    a("--no-shells", action="store_true", help="with --map estimate: keep the spectral map when "
      "it is doubtful (by default a full match between meshes then also registers the shapes' "
      "smooth shells, about 6 s at 5k vertices, a --partial match the part onto the whole, "
      "3-5 s, and keeps the map that distorts less)")
    a("--same-frame", action="store_true", help="with --map estimate: the shapes are given in one "
      "frame (upright, facing the same way): a shells registration that fits with front and "
      "back swapped about as well as the right way round keeps that frame")
    a("--target-scale", type=positive_float, metavar="FACTOR", help="one target in other units "
      "than the source: its coordinates times FACTOR for the run (0.001: millimetres onto "
      "metres); the result is written in its own units")
    a("--save-map", metavar="MAP.npz", help="write the map used (to reuse: --map)")
    a("--strict", action="store_true", help="a suspect map (estimated, closest, or a map file that "
      "collapses) is an error (exit 3; nothing written but --save-landmarks)")
    a("--landmarks", help="known (source, target) vertex pairs, 0-based: 12:40,500:611 (or ;), a "
      "2-column file (spaces, commas or semicolons apart; FILE.vts 1-based, as --map's), or "
      "'pick' (in Open3D's window)")
    a("--save-landmarks", metavar="FILE", help="write the landmark pairs used (e.g. picked) as a "
      "2-column file (FILE.vts 1-based; to reuse: --landmarks FILE)")
    a("--basis-1", help="cached source basis (.npz from 'o3d-ofp basis')")
    a("--basis-2", help="cached target basis (.npz from 'o3d-ofp basis')")  # fmt: skip


# --------------------------------------------------------------------------- reading


def _obj_vertex_lines(path: str) -> int:
    """Count the ``v`` lines of an OBJ file (its own vertex numbering)."""
    count = 0
    with open(path, "rb") as f:
        for line in f:
            count += line.startswith(b"v ") or line.startswith(b"v\t")
    return count


def _say_renumbered(shapes: tuple[tuple[str, int], ...]) -> None:
    """Warn when an OBJ is read with other vertices than its ``v`` lines (landmarks given).

    Open3D splits an OBJ's vertices along its texture seams (a new-user trial: Spot, 2930 ``v``
    lines, 3225 vertices read, no index agreeing): indices taken from another tool, which
    counts the file's lines, would name other vertices.
    """
    for path, n in shapes:
        if not str(path).lower().endswith(".obj") or not os.path.isfile(path):
            continue
        lines = _obj_vertex_lines(path)
        if lines != n:
            logger.warning(
                "--landmarks: %s has %d 'v' lines but is read as %d vertices (split along its "
                "texture seams): the landmarks index the vertices as read (as "
                "open3d.io.read_triangle_mesh numbers them), not the file's lines; indices "
                "from another tool name other vertices: pick them with --landmarks pick",
                path, lines, n,
            )  # fmt: skip


def _landmarks(spec: str | None, shapes: tuple[Any, Any], n1: int, n2: int) -> np.ndarray | None:
    """Return the pairs of ``--landmarks``: picked on ``shapes``, or a file or inline pairs.

    Those read are checked to lie in both shapes.
    """
    if not spec:
        return None
    if spec == "pick":
        try:
            return pick_landmarks(*shapes)
        except (ValueError, RuntimeError) as exc:
            raise UsageError(f"--landmarks pick: {exc}") from exc
    is_file = os.path.isfile(spec)
    common.refuse((not is_file and (":" not in spec or os.sep in spec),
                   f"--landmarks {spec}: no such file (or give pairs like 12:40,500:611)"))
    try:  # utf-8-sig: a spreadsheet's "CSV UTF-8" starts with a byte-order mark
        with open(spec, encoding="utf-8-sig") if is_file else contextlib.nullcontext(
            spec.replace(":", " ").replace(";", ",").split(",")
        ) as lines, warnings.catch_warnings():  # fmt: skip
            warnings.simplefilter("ignore", UserWarning)  # "no data": said below
            apart = (line.replace(",", " ").replace(";", " ") for line in lines)  # (CSVs too)
            pairs = np.loadtxt(apart, ndmin=2)
    except (ValueError, UnicodeDecodeError) as exc:
        # numpy's message for a ragged file ends with advice for its own API ("; use `usecols`
        # to select a subset ..."): only what precedes it is about the file
        said = str(exc).split("; use `usecols`")[0]
        raise UsageError(f"--landmarks {spec}: not {'a text file of ' * is_file}two integer "
                         "columns (source vertex, target vertex; '#' starts a comment): "
                         f"{said}") from exc  # fmt: skip
    columns = pairs.shape[1] if pairs.size else 2
    common.refuse(
        (columns != 2, f"--landmarks {spec}: {columns} column{'s' * (columns > 1)}; the "
         f"{'file' if is_file else 'value'} needs two (source vertex, target vertex, 0-based) on "
         f"each {'line' if is_file else 'pair'}"),
        (not pairs.size, f"--landmarks {spec}: no pairs in the file"),
        (not np.all(np.isfinite(pairs)) or np.any(pairs != np.round(pairs)),
         f"--landmarks {spec}: the values must be integer vertex indices"),
    )  # fmt: skip
    first = _first_index(spec) if is_file else 0
    pairs = pairs.astype(np.int64)
    for col, n, name in ((0, n1, "source"), (1, n2, "target")):
        outside = np.flatnonzero((pairs[:, col] < first) | (pairs[:, col] >= n + first))
        if outside.size:  # the first pair outside, by its place in the file or the value
            row = int(outside[0])
            where = f"line {_data_line(spec, row)}" if is_file else f"pair {row + 1}"
            raise UsageError(f"--landmarks {spec}: {name} indices must lie in [{first}, "
                             f"{n + first}) ({first}-based); got {pairs[row, col]} in {where} "
                             f"({pairs[row, 0]} {pairs[row, 1]})")  # fmt: skip
    return pairs - first


def _first_index(path: str) -> int:
    """Return where a landmark file counts from: 1 for ``.vts`` (as ``--map FILE.vts``), else 0."""
    return 1 if path.lower().endswith(".vts") else 0


def _data_line(path: str, row: int) -> int:
    """Return the 1-based line of a text file that holds its ``row``-th pair (0-based).

    Lines that hold no data (empty, or a '#' comment) are skipped, as ``numpy.loadtxt`` does.
    """
    with open(path, encoding="utf-8-sig") as fh:
        data = (i for i, line in enumerate(fh, 1) if line.split("#")[0].strip())
        return next(itertools.islice(data, row, None), row + 1)


def _check_extra_output(args: argparse.Namespace, path: str, flag: str, inputs: Any) -> None:
    """Refuse a ``--save-map`` / ``--save-landmarks`` file that would replace another file.

    That is an input of the command, the result or a file written beside it, the other such
    file, or a cache entry.
    """
    files = [("the --map file read", f) for f in args.map.split(",")]
    files += [("an input of this command", f) for f in inputs]
    beside = (*common.written_beside(args.output), *common.signal_sides(args))
    files += [("the -o output", args.output), *(("written with -o", f) for f in beside)]
    files += [(f"the {o} file", getattr(args, common.dest(o)))
              for o in ("--save-map", "--save-landmarks") if o != flag]  # fmt: skip
    cache = args.cache and os.path.dirname(os.path.abspath(path)) == os.path.abspath(args.cache)
    common.refuse(*((isinstance(f, str) and f and common.same_file(path, f), f"{flag} {path}: is "
                     f"{what}; it would be overwritten") for what, f in files),
                  (cache, f"{flag} {path}: is in the --cache folder {args.cache}; choose another"))


def _check_flags(args: argparse.Namespace, inputs: Any) -> None:
    """Refuse flags that contradict each other, and bad side outputs, before reading."""
    lm, save, kind = args.landmarks, args.save_landmarks, args.map
    partial = "" if kind in ("closest", "identity") else (
        ", a map used as it is (a map saved from a run with --partial is partial already)")
    frame = same_frame_conflict(partial=args.partial, landmarks=bool(lm), shells=not args.no_shells)
    common.refuse(
        (lm == "", "--landmarks is empty: give pairs like 12:40,500:611, a 2-column file or "
         "'pick'"),
        (save and not lm, "--save-landmarks needs --landmarks (pick, pairs or a file)"),
        (save and os.path.isdir(save), f"--save-landmarks {save}: is a directory"),
        (lm == "pick" and kind != "estimate", "--landmarks pick applies to --map estimate"),
        (lm == "pick" and not has_display(), "--landmarks pick needs a display to open Open3D's "
         "picking window (no X11 or Wayland server answers: DISPLAY and WAYLAND_DISPLAY are not "
         "set, or nothing listens there); give the pairs in a file "
         "instead: --landmarks FILE (two columns: source vertex, target vertex)"),
        (args.save_map and not args.save_map.endswith(".npz"),
         f"--save-map {args.save_map}: must end with .npz"),
        (args.align and kind != "closest", "--align applies to --map closest"),
        *((on and kind != "estimate", f"{flag} applies to --map estimate, not --map {kind}")
          for flag, on in (("--no-shells", args.no_shells), ("--same-frame", args.same_frame))),
        (args.same_frame and kind == "estimate" and frame is not None,
         f"--same-frame {frame and frame.text(cli=True)}"),
        (args.partial and kind != "estimate", "--partial applies to --map estimate (the partial "
         f"match), not to --map {kind}{partial}: drop --partial"),
        (lm and kind != "estimate", f"--landmarks apply to --map estimate, not --map {kind}"),
        (args.target_scale is not None and args.basis_2, f"--basis-2 {args.basis_2} holds the "
         f"basis of {args.target} in its own units, and --target-scale changes them: drop "
         "--basis-2 (--cache DIR keeps the scaled target's basis apart)"),
    )  # fmt: skip
    for path, flag in ((save, "--save-landmarks"), (args.save_map, "--save-map")):
        if path:
            _check_extra_output(args, path, flag, inputs)
            common.check_writable_folder(os.path.dirname(os.path.abspath(path)), path, flag=flag)


def _identity(n1: int, n2: int, V1: np.ndarray, V2: np.ndarray) -> Correspondence:
    """Return the map of ``--map identity`` (refused between other vertex counts)."""
    if n1 == n2:  # (a saved map remembers its shapes, as every other map does)
        return with_signatures(
            Correspondence(p2p_21=np.arange(n2), n_source=n1, method="identity"), V1, V2
        )
    copies = [f"{extra} of the {name}'s are copies at the same position as another (e.g. an "
              "OBJ's along its UV seams)" for name, V in (("source", V1), ("target", V2))
              if (extra := V.shape[0] - np.unique(V, axis=0).shape[0])]
    raise UsageError(f"--map identity needs shapes with the same vertices; got {n1} and {n2}"
                     + (f" ({'; '.join(copies)})" if copies else "")
                     + ": --map closest maps shapes in the same place whatever their vertices")


def _read_map(
    spec: str, V1: np.ndarray, V2: np.ndarray, F1: np.ndarray | None = None,
    F2: np.ndarray | None = None,
) -> tuple[Correspondence | None, Said | None]:  # fmt: skip
    """Read the Correspondence named by ``--map`` (None: made by the plan), checked for both.

    Two template files fill the target vertices they do not list along the target's edges
    (``F2``; in space for a cloud), and say how many they list; the second value says why
    they do not fit these shapes (:func:`~o3d_ofp.workflows.maps.template_misfit`), else None.
    """
    n1, n2 = V1.shape[0], V2.shape[0]
    if spec in ("estimate", "closest", "identity"):
        return (_identity(n1, n2, V1, V2) if spec == "identity" else None), None
    files = spec.split(",")
    path, method, misfit = files[0], "given", None
    common.refuse(
        *((not os.path.isfile(f), f"--map {f}: no such map file (--map estimate|closest|identity|"
           "MAP.npz|FILE[,FILE])") for f in files),
        (len(files) > 2, f"--map takes one file or two comma-separated .vts files; got {spec!r}"),
        (len(files) == 1 and path.lower().endswith(common.GEOMETRY_OUT), f"--map {path}: a mesh or "
         "point-cloud file, not a map (--map estimate|closest|identity|MAP.npz|FILE.vts|FILE.npy|"
         "SRC.vts,TGT.vts); the shapes are the positional arguments"),
    )  # fmt: skip
    try:
        if len(files) == 2:  # correspondences of both shapes to a common template
            rows_1, rows_2 = read_vts(files[0]), read_vts(files[1])
            p2p, method = p2p_from_template(rows_1, rows_2, V2, faces_2=F2), "template"
            listed = np.unique(rows_2).size
            along = "along the target's surface" if F2 is not None else "in space"
            report([f"--map {spec}: {listed} of the target's {n2} vertices listed "
                    f"({listed / n2:.1%}); each other takes the source vertex of the listed "
                    f"one nearest {along}"])  # fmt: skip
        elif path.endswith(".npz"):
            corr = Correspondence.load(path)
            corr.check(n1, n2, name=f"--map {path}")
            return corr, None
        elif path.endswith(".npy"):
            p2p = common.load_npy(path, "0-based target->source map", flag="--map")
        else:
            p2p = read_vts(path)
    except (ValueError, TypeError) as exc:
        said = str(exc) if len(files) == 1 else f"{spec}: {exc}"
        raise UsageError(said if said.startswith("--map") else f"--map {said}") from exc
    p2p = np.asarray(p2p)
    common.refuse((p2p.shape != (n2,) or not np.issubdtype(p2p.dtype, np.integer), f"--map {path}: "
                   f"a map file lists one source vertex per target vertex ({n2} integers); got "
                   f"shape {p2p.shape} and dtype {p2p.dtype}"))  # fmt: skip
    first = 0 if path.endswith(".npy") else 1  # (a .vts file counts from 1; read 0-based)
    common.refuse((p2p.min() < 0 or p2p.max() >= n1, f"--map {path}: source vertices must lie in "
                   f"[{first}, {n1 - 1 + first}] ({first}-based); got [{p2p.min() + first}, "
                   f"{p2p.max() + first}]"))  # fmt: skip
    if method == "template":  # (its source rows are in range: checked above)
        misfit = template_misfit(rows_1, rows_2, V1, F1, V2, F2)
    return with_signatures(Correspondence(p2p_21=p2p, n_source=n1, method=method), V1, V2), misfit


def _other_numbering(F1: np.ndarray | None, F2: np.ndarray | None) -> str | None:
    """Why ``--map identity`` is doubtful between two meshes: their triangles differ."""
    if F1 is None or F2 is None:
        return None
    # every triangle (its corners sorted) labelled by its distinct row among both meshes'
    _, label = unique_rows(np.sort(np.concatenate([F1, F2]), axis=1), return_inverse=True)
    other = int(np.count_nonzero(~np.isin(label[len(F1):], label[: len(F1)])))
    if not other:
        return None
    return (f"--map identity: {other} of the target's {len(F2)} triangles are not the source's: "
            "the two meshes are numbered differently (renumbered or remeshed), so vertex i of "
            "one need not be vertex i of the other; --map estimate or --map closest find the "
            "map")  # fmt: skip


def _judge_given(
    args: argparse.Namespace, corr: Any, V1: np.ndarray, V2: np.ndarray,
    faces: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
    misfit: Said | None = None,
) -> None:  # fmt: skip
    """Say when a map read from a file is doubtful; ``--strict`` makes that an error.

    ``misfit``: why two template files do not fit the shapes (from :func:`_read_map`).

    A map that collapses (:func:`o3d_ofp.workflows.maps.given_map_collapse`: a few flat
    values), one saved by ``--save-map`` whose stored quality is suspect or that was made for
    other shapes (source and target swapped, another pair with the same vertex counts), and
    ``--map identity`` between meshes whose triangles differ (``faces``: another numbering).
    The library warns of the first and the others' kind when the map is used; the stored
    verdict and the numbering are warned here.
    """
    collapse = given_map_collapse(corr.p2p_21, V1.shape[0], V2.shape[0])
    numbering = _other_numbering(*faces) if corr.method == "identity" else None
    reasons = [r for r in (collapse and f"--map {args.map}: {collapse.text(cli=True)}",
                           misfit and f"--map {args.map}: {misfit.text(cli=True)}",
                           corr.mismatch(V1, V2, name=f"--map {args.map}"), numbering)
               if r]  # fmt: skip
    if numbering and not args.strict:
        logger.warning("%s", numbering)
    quality = corr.quality
    if quality is not None:
        # (the verdict of its own estimation, when saved; the checks here are this use's)
        report([f"when saved, --map {args.map} had {quality.summary()}"])
    if quality is not None and quality.suspect:
        # said once: on stderr (its summary line above already says SUSPECT on stdout)
        said = "; ".join(r.text(cli=True) for r in quality.reasons)
        saved = f"--map {args.map} was saved with a suspect quality: {said}"
        if args.strict:
            reasons.append(saved)
        else:
            logger.warning("%s", saved)
    if reasons and args.strict:
        raise SuspectMap("; ".join(reasons))
    report([f"map quality SUSPECT: {reason}" for reason in reasons])


def read_pair(args: argparse.Namespace, outputs: tuple[str, ...]) -> Pair:
    """Check ``-o`` (one of ``outputs``), read both shapes, the map and the landmarks.

    Everything that fails fast.
    """
    inputs = (args.source, args.target, getattr(args, "signal", None), getattr(args, "texture",
              None), *args.map.split(","), args.landmarks, args.basis_1, args.basis_2)  # fmt: skip
    common.check_output(args.output, outputs, inputs=inputs, side=common.signal_sides(args))
    common.check_folder_to_make(args.cache, "--cache")
    _check_flags(args, inputs)
    source, V1, F1 = common.read_shape(args.source)
    target, V2, F2 = common.read_shape(args.target)
    common.check_output_kind(args.output, F2)
    factor, own = args.target_scale, target
    if factor is not None:  # every step below sees the target in the source's units
        target, V2 = scaled_copy(target, factor), V2 * factor
    given, misfit = _read_map(args.map, V1, V2, F1, F2)
    if given is not None:
        _judge_given(args, given, V1, V2, (F1, F2), misfit)
    landmarks = _landmarks(args.landmarks, (source, target), V1.shape[0], V2.shape[0])
    if landmarks is not None and args.landmarks != "pick":  # (picked ones are as read)
        _say_renumbered(((args.source, V1.shape[0]), (args.target, V2.shape[0])))
    options = MatchOptions(method="closest" if args.map == "closest" else "estimate",
                           partial=args.partial, align=args.align, landmarks=landmarks,
                           components=args.components, shells=not args.no_shells,
                           same_frame=args.same_frame)  # fmt: skip
    if options.landmarks is not None and args.save_landmarks:
        first = _first_index(args.save_landmarks)
        with atomic_path(args.save_landmarks, suffix=".txt") as tmp:
            np.savetxt(tmp, np.asarray(options.landmarks) + first, fmt="%d",
                       header=f"source_vertex target_vertex ({first}-based)")  # fmt: skip
        report([f"wrote {len(options.landmarks)} landmark pairs to {args.save_landmarks}"])
    scaled = args.target if factor is None else f"{args.target} scaled by {factor:g}"
    return Pair(source, target, V1, F1, V2, F2, given, options, (args.source, scaled), own,
                factor, inputs=inputs)  # fmt: skip


# --------------------------------------------------------------------------- planning


def plan(args: argparse.Namespace, pair: Pair, task: str, *, unused: Callable[[list[str]], str],
         files: bool = False, **options: Any) -> Plan:  # fmt: skip
    """Return the plan of the job (:func:`o3d_ofp.workflows.plan.plan_pair`) for the flags.

    The OFP basis flags given to a job the plan makes without OFP bases (and, with ``files``,
    the basis files) are refused with ``unused(flags given)``, in the command line's words;
    then the basis files are read and planned with (the plan refuses two thresholds).
    ``options``: ``detail``, ``via_basis`` of :func:`plan_pair`.
    """
    planned = _planned(pair, task=task, **options)
    named = [f for f in (*common.FLAGS["options"], *common.FLAGS["bases"][: 2 * files])
             if getattr(args, common.dest(f)) is not None]  # fmt: skip
    common.refuse((planned.basis_k is None and named, unused(named)))
    sides = ((args.basis_1, pair.V1, pair.F1, args.source, "--basis-1"),
             (args.basis_2, pair.V2, pair.F2, args.target, "--basis-2"))
    pair.files = tuple(common.load_basis_file(f, V, F, path, args, flag) if f else None
                       for f, V, F, path, flag in sides)  # fmt: skip
    bases = common.basis_options(args)
    tol = (bases or BasisOptions()).threshold("ours")
    for B, (f, *_, flag), k_flag in zip(pair.files, sides, ("--k1", "--k2"), strict=True):
        if B is not None:  # its flags must say what the file holds
            common.check_basis_flags(B, f"{flag} {f}", args, k_flag, getattr(args, k_flag[2:]),
                                     tol)  # fmt: skip
    if planned.basis_k is not None and (bases is not None or any(pair.files)):
        planned = _planned(pair, task=task, bases=bases, given_bases=pair.files, **options)
    return planned


def _planned(pair: Pair, **options: Any) -> Plan:
    """Return :func:`plan_pair`'s plan.

    A part refused for its area with ``--target-scale`` says the factor that would admit the
    file itself.
    """
    try:
        return plan_pair(pair.V1, pair.F1, pair.V2, pair.F2, match=pair.match, given=pair.given,
                         names=pair.names, **options)  # fmt: skip
    except AdvisedError as exc:
        factor = pair.target_scale
        if factor is None or exc.said.code not in ("part_larger", "part_too_small"):
            raise
        target = pair.names[1].rpartition(" scaled by ")[0]
        try:  # the advice for the file as it is, whose factor is the one to give
            check_partial_areas(pair.V1, pair.F1, pair.V2 / factor, pair.F2,
                                names=(pair.names[0], target))  # fmt: skip
        except AdvisedError as own:
            raise UsageError(Said("--target-scale {factor:g} does not fix the units: {own}",
                                  {"factor": factor, "own": own.said})) from exc  # fmt: skip
        raise UsageError(Said("--target-scale {factor:g}: {said}; {target} as it is would be "
                              "admitted: drop --target-scale",
                              {"factor": factor, "said": exc.said, "target": target})) from exc


# --------------------------------------------------------------------------- running


def prepare_pair(args: argparse.Namespace, pair: Pair, planned: Plan) -> Prepared:
    """Run the plan (:func:`o3d_ofp.workflows.plan.prepare`), a closest-point map first.

    Its eigenbases, estimated map and OFP bases; the map's quality printed (``--strict``), the
    map saved (``--save-map``).
    """
    given = pair.given
    if planned.estimator == "closest":
        with stage("closest points on the source surface"):
            given = match(pair.source, pair.target, options=pair.match)
        report_quality(args, given)
    progress = stage_progress("matching") if planned.estimated else contextlib.nullcontext()
    with stage(_describe(planned, pair), ticking=not planned.estimated), progress as tell:
        prepared = prepare(planned, pair.V1, pair.F1, pair.V2, pair.F2, match=pair.match,
                           given=given, bases=pair.files, cache_dir=args.cache, progress=tell,
                           names=pair.names)  # fmt: skip
    if planned.estimated:
        report_quality(args, prepared.correspondence)
    if args.save_map:
        prepared.correspondence.save(args.save_map)
        report([f"wrote the map to {args.save_map}"])
    return prepared


def _describe(planned: Plan, pair: Pair) -> str:
    """Say what :func:`prepare` computes for the plan, for its stage line ("" for nothing)."""
    todo = [(name, k, only) for name, k, B, only in zip(
        pair.names, planned.eig_k, pair.files, planned.operators, strict=True
    ) if k and (B is None or B.eig.k < k)]  # fmt: skip
    eig = [f"{name} (k={k})" for name, k, only in todo if not only]
    parts = ["eigenbases of " + " and ".join(eig)] if eig else []
    operators = [name for name, _, only in todo if only]  # the calibrated detail's
    if operators:
        parts.append("Laplace-Beltrami operators of " + " and ".join(operators))
    if planned.basis_k and None in pair.files:
        parts.append(f"OFP bases (k={planned.basis_k[0]} and {planned.basis_k[1]}, order "
                     f"{planned.order})")  # fmt: skip
    n = max(pair.V1.shape[0], pair.V2.shape[0])
    parts.append(f"map estimation on coarse copies ({n} vertices: dense path)" if planned.dense
                 else _ESTIMATION.get(planned.estimator, ""))  # fmt: skip
    return ", ".join(p for p in parts if p)


def report_quality(args: argparse.Namespace, corr: Correspondence) -> None:
    """Print a made map's quality report; ``--strict`` turns a suspect one into an error."""
    quality = corr.quality
    assert quality is not None
    report([quality.summary(), *quality.notes])
    if quality.suspect and args.strict:
        raise SuspectMap("; ".join(r.text(cli=True) for r in quality.reasons))


def map_name(args: argparse.Namespace, corr: Correspondence) -> str:
    """How the map was made, and from which file when it was read (``ab.npz (estimate)``)."""
    if args.map in ("estimate", "closest", "identity") or corr.method == args.map:
        return str(corr.method)
    return f"{args.map} ({corr.method})"
