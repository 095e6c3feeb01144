"""``o3d-ofp detail``: give the target the source's geometric detail."""

from __future__ import annotations

import argparse

from ..workflows.options import DETAIL_MODES, MAX_AMOUNT, DetailOptions
from ._common import (
    CLOUD_OUT,
    MESH_OUT,
    UsageError,
    basis_options,
    check_output,
    check_output_kind,
    flag_of,
    renamed,
    report,
    stage,
)
from ._many import (
    PAIR_ONLY,
    add_collection_options,
    check_single,
    is_collection,
    refuse_flags,
    run_transfers,
)
from ._pair import add_pair_options, plan, prepare_pair, read_pair
from ._types import bounded_float, positive_int

__all__ = ["add_parser", "run"]

_MODE_HELP = (
    "add: the target keeps its pose, shape and own detail and gains the source's detail (above "
    "--band eigenfunctions) in its local frames; replace-detail: the target's own detail is "
    "replaced by the source's; coordinates: the paper's Fig. 13, the source's coordinates "
    "transferred with OFP bases replace the target's (the target takes the source's pose; uses "
    "--k1/--k2/--order/--preset); replace: deprecated name of coordinates. Default: add"
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    default = DetailOptions()
    p = sub.add_parser("detail", help="give the target the source's geometric detail")
    add_pair_options(p, preset="ours*", several=True)
    p.add_argument("--mode", choices=(*DETAIL_MODES, "replace"), default=default.mode,
                   help=_MODE_HELP)  # fmt: skip
    p.add_argument(
        "--band", type=positive_int,
        help="the detail is what lies above this many eigenfunctions, the same at every "
        f"resolution and scale ({default.band}); lower takes more of the source's shape",
    )  # fmt: skip
    p.add_argument("--amount", type=bounded_float(0.0, MAX_AMOUNT),
                   help=f"multiplies the transferred detail, in [0, {MAX_AMOUNT:g}] "
                   f"({default.amount:g})")  # fmt: skip
    p.add_argument("--k-low", type=positive_int, help="deprecated name of --band")
    p.add_argument("-o", "--output", required=True,
                   help="displaced target; with several targets a folder")  # fmt: skip
    add_collection_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Check the flags, then transfer the detail to the target (or to each target)."""
    from ..boundary.api import transfer_detail
    from ..boundary.io import write_geometry

    renamed(args)  # --k-low, --mode replace
    if args.band is not None and args.mode == "coordinates":
        raise UsageError(f"{flag_of('band')} does not apply to --mode coordinates (it has no "
                         "detail band)")  # fmt: skip
    given = {n: getattr(args, n) for n in ("mode", "band", "amount")}
    given = {name: value for name, value in given.items() if value is not None}
    if is_collection(args.target):
        refuse_flags(args, PAIR_ONLY)
        return run_transfers(args, kind="detail", options=given)
    check_single(args)
    args.target = args.target[0]
    inputs = (args.source, args.target)
    check_output(args.output, (*MESH_OUT, *CLOUD_OUT), inputs=inputs)
    detail = DetailOptions(**given)
    pair = read_pair(args)
    check_output_kind(args.output, pair.F2)

    def unused(named: list[str]) -> str:
        band = flag_of("band")
        return (f"{', '.join(named)} {'applies' if len(named) == 1 else 'apply'} to --mode "
                f"coordinates (the OFP bases); --mode {detail.mode} reads each shape's "
                f"eigenfunctions up to {band} ({detail.band}): drop "
                f"{'it' if len(named) == 1 else 'them'}, or set {band}")  # fmt: skip

    planned = plan(args, pair, "detail", unused=unused, detail=detail)
    prepared = prepare_pair(args, pair, planned)
    with stage(f"detail transfer ({detail.mode})"):
        moved = transfer_detail(
            pair.source, pair.target, correspondence=prepared.correspondence, mode=detail.mode,
            band=detail.band, amount=detail.amount, options=basis_options(args),
            bases=prepared.bases or (prepared.eig_1, prepared.eig_2),
        )  # fmt: skip
    write_geometry(args.output, pair.in_target_units(moved), protect=inputs)
    what = detail.mode if detail.mode == "coordinates" else f"{detail.mode}, band {detail.band}"
    report([f"{args.source} -> {args.target}: detail ({what})", f"wrote {args.output}"])
    return 0
