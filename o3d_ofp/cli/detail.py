"""``o3d-ofp detail``: give the target the source's geometric detail.

The per-pair work is :func:`detail_one` (one target, one output), so that several targets can
share one parsed command line.
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

from ..workflows.detail import DETAIL_BAND, MAX_AMOUNT, MODES, ROTATION_K
from ._common import (
    CLOUD_OUT,
    MESH_OUT,
    UsageError,
    check_output,
    check_output_kind,
    load_basis_file,
    report,
    stage,
    tol_options,
)
from ._many import (
    PAIR_ONLY,
    add_collection_options,
    check_single,
    is_collection,
    refuse_flags,
    run_transfers,
)
from ._pair import (
    add_pair_options,
    bases_for_pair,
    estimate_or_use_map,
    map_first,
    read_pair,
)
from ._types import bounded_float, positive_int

__all__ = ["add_parser", "check_options", "detail_one", "run"]

logger = logging.getLogger(__name__)

_MODE_HELP = (
    "add: the target keeps its pose, shape and own detail and gains the source's detail "
    "(above --band eigenfunctions) in its local frames; replace-detail: the target's own "
    "detail is replaced by the source's; coordinates: the paper's Fig. 13, the source's "
    "coordinates transferred with OFP bases replace the target's (the target takes the "
    "source's pose; uses --k1/--k2/--order/--preset); replace: deprecated name of "
    "coordinates. Default: add"
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("detail", help="give the target the source's geometric detail")
    add_pair_options(p, preset="ours*", several=True)
    p.add_argument("--mode", choices=(*MODES, "replace"), default="add", help=_MODE_HELP)
    p.add_argument(
        "--band",
        type=positive_int,
        help=f"the detail is what lies above this many eigenfunctions, the same at every "
        f"resolution and scale ({DETAIL_BAND}); lower takes more of the source's shape",
    )
    p.add_argument(
        "--amount",
        type=bounded_float(0.0, MAX_AMOUNT),
        default=1.0,
        help=f"multiplies the transferred detail, in [0, {MAX_AMOUNT:g}] (1)",
    )
    p.add_argument("--k-low", type=positive_int, help="deprecated name of --band")
    p.add_argument(
        "-o", "--output", required=True, help="displaced target; with several targets a folder"
    )
    add_collection_options(p)
    p.set_defaults(func=run)


def check_options(args: argparse.Namespace) -> None:
    """Check the detail flags against each other (before reading anything); normalize them.

    Sets ``args.band`` (from ``--band``, ``--k-low`` or the default) and turns the deprecated
    ``--mode replace`` into ``coordinates``.

    Raises
    ------
    UsageError
        Naming the flag.
    """
    if args.mode == "replace":
        logger.warning("--mode replace is deprecated; use --mode coordinates")
        args.mode = "coordinates"
    flag = "--band"
    if args.k_low is not None:
        logger.warning("--k-low is deprecated; use --band")
        if args.band is not None and args.band != args.k_low:
            raise UsageError(f"--k-low {args.k_low} and --band {args.band} disagree: give --band")
        args.band, flag = args.k_low, "--k-low"
    if args.band is None:
        args.band = DETAIL_BAND
    elif args.mode == "coordinates":
        raise UsageError(f"{flag} does not apply to --mode coordinates (it has no detail band)")
    args.band_flag = flag
    if args.mode != "coordinates":
        # The OFP bases' flags do nothing here (a trial's --k1 50 gave the same result, and
        # only cost eigenfunctions): said, as the closest map's exact pull-back says them.
        given = getattr(args, "given", set()) or set()
        unused = [f"--k{side}" for side in (1, 2) if getattr(args, f"k{side}") is not None]
        unused += [f"--{name}" for name in ("order", "preset", "tol") if name in given]
        if unused:
            raise UsageError(
                f"{', '.join(unused)} {'applies' if len(unused) == 1 else 'apply'} to --mode "
                f"coordinates (the OFP bases); --mode {args.mode} reads each shape's "
                f"eigenfunctions up to {flag} ({args.band}): drop "
                f"{'it' if len(unused) == 1 else 'them'}, or set {flag}"
            )


def _eigenbases(args: argparse.Namespace, pair: Any) -> tuple[Any, Any]:
    """Eigenbases for the detail modes: --band (and the map estimation) decide their size."""
    from ..workflows.matching import ESTIMATION_K, required_k
    from ._common import check_job_memory, eigenbases_of

    estimate = pair.correspondence is None
    sides = [(args.source, pair.V1, pair.F1, args.basis_1)]
    sides.append((args.target, pair.V2, pair.F2, args.basis_2))
    wants = []
    for path, V, _, _ in sides:
        need = max(args.band, ROTATION_K)
        if need > V.shape[0] - 2:
            raise UsageError(
                f"{args.band_flag} {args.band}: {path} has {V.shape[0]} vertices, too few for "
                f"{need} eigenfunctions (lower {args.band_flag})"
            )
        wants.append(max(need, required_k(V.shape[0], ESTIMATION_K)) if estimate else need)
    check_job_memory(
        [
            (path, V.shape[0], want, want, 1)
            for (path, V, *_), want in zip(sides, wants, strict=True)
        ],
        advice=f"lower {args.band_flag}, or use simplified meshes (fewer vertices)",
    )
    # Basis files: their eigenbases, when large enough (their OFP bases are not used here, and
    # no OFP basis is made for a side without one).
    out = []
    for side, ((path, V, F, file), want) in enumerate(zip(sides, wants, strict=True), start=1):
        eig = load_basis_file(file, V, F, path, args, f"--basis-{side}").eig if file else None
        if eig is not None and eig.k < want:
            logger.info("--basis-%d %s: %d eigenfunctions, %d are needed: computing them",
                        side, file, eig.k, want)  # fmt: skip
            eig = None
        out.append(eig)
    todo = [i for i, eig in enumerate(out) if eig is None]
    if todo:
        names = " and ".join(f"{sides[i][0]} ({sides[i][1].shape[0]} vertices, k={wants[i]})"
                             for i in todo)  # fmt: skip
        with stage(f"eigenbases of {names}" if len(todo) > 1 else f"eigenbasis of {names}"):
            computed = eigenbases_of(
                args, [(*sides[i][:3], wants[i]) for i in todo], clamp_k=estimate
            )
        for i, eig in zip(todo, computed, strict=True):
            out[i] = eig
    return out[0], out[1]


def detail_one(args: argparse.Namespace, target_path: str, output_path: str) -> list[str]:
    """Read, match (or read the map), move one target's vertices, write; return report lines.

    ``args`` must have passed :func:`check_options`.
    """
    from ..boundary.api import transfer_detail
    from ..boundary.io import write_geometry

    check_output(output_path, (*MESH_OUT, *CLOUD_OUT), inputs=(args.source, target_path))
    one = argparse.Namespace(**{**vars(args), "target": target_path})
    pair = read_pair(one)
    check_output_kind(output_path, pair.F2)
    pair = map_first(one, pair)
    if args.mode == "coordinates":
        B1, B2, eig_1, eig_2 = bases_for_pair(one, pair)
        ofp_options = dict(k1=B1.k, k2=B2.k, order=args.order, bases=(B1, B2), **tol_options(args))
    else:
        eig_1, eig_2 = _eigenbases(one, pair)
        ofp_options = {}
    corr = estimate_or_use_map(one, pair, eig_1, eig_2)
    with stage(f"detail transfer ({args.mode})"):
        moved = transfer_detail(
            pair.source,
            pair.target,
            mode=args.mode,
            band=args.band,
            amount=args.amount,
            correspondence=corr,
            eigenbases=(eig_1, eig_2),
            **ofp_options,
        )
    write_geometry(output_path, pair.in_target_units(moved), protect=(args.source, target_path))
    what = args.mode if args.mode == "coordinates" else f"{args.mode}, band {args.band}"
    return [f"{args.source} -> {target_path}: detail ({what})", f"wrote {output_path}"]


def run(args: argparse.Namespace) -> int:
    """Check the flags, then transfer the detail to the target (or to each target)."""
    if is_collection(args.target):
        refuse_flags(args, PAIR_ONLY)
        check_options(args)
        options = {"k1": args.k1, "k2": args.k2, "mode": args.mode, "band": args.band,
                   "amount": args.amount}  # fmt: skip
        return run_transfers(args, kind="detail", options=options)
    check_single(args)
    args.target = args.target[0]
    check_output(args.output, (*MESH_OUT, *CLOUD_OUT), inputs=(args.source, args.target))
    check_options(args)
    report(detail_one(args, args.target, args.output))
    return 0
