"""``o3d-ofp detail``: give the target the source's geometric detail."""

from __future__ import annotations

import argparse

from ..boundary.api import transfer_detail
from ..boundary.io import write_geometry
from ..workflows.options import DETAIL_MODES, MAX_AMOUNT, DetailOptions
from . import _common as common
from ._common import bounded_float, positive_int, report, stage
from ._pair import add_pair_options, plan, prepare_pair, read_pair

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    default = DetailOptions()
    p = sub.add_parser("detail", help="give the target the source's geometric detail")
    add_pair_options(p, preset="ours*", several=True)
    a = p.add_argument
    a("--mode", choices=(*DETAIL_MODES, "replace"), default=default.mode, help="add: the target "
      "gains the detail it lacks, in its local frames; replace-detail: its own detail is replaced; "
      "coordinates (Fig. 13): the source's coordinates through the OFP bases (--k1/--k2/--order/"
      f"--preset) replace the target's; replace: deprecated name of coordinates ({default.mode})")
    a("--band", type=positive_int, help="add the detail above this many eigenfunctions everywhere "
      "(lower takes more shape); default: what the target lacks, calibrated on the two shapes")
    a("--amount", type=bounded_float(0.0, MAX_AMOUNT), help="multiplies the transferred detail, in "
      f"[0, {MAX_AMOUNT:g}] ({default.amount:g})")
    a("--k-low", type=positive_int, help="deprecated name of --band")
    a("-o", "--output", required=True, help="displaced target; with several targets a folder")
    common.add_collection_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Check the flags, then transfer the detail to the target (or to each target)."""
    common.renamed(args)  # --k-low, --mode replace
    common.refuse((args.band is not None and args.mode == "coordinates",
                   f"{common.flag_of('band')} does not apply to --mode coordinates (it has no "
                   "detail band)"))  # fmt: skip
    given = {n: v for n in ("mode", "band", "amount") if (v := getattr(args, n)) is not None}
    if not common.single(args, "target"):
        return common.run_transfers(args, kind="detail", options=given)
    detail = DetailOptions(**given)
    pair = read_pair(args, common.GEOMETRY_OUT)
    planned = plan(args, pair, "detail", detail=detail, unused=lambda named: (
        f"{', '.join(named)} {'applies' if len(named) == 1 else 'apply'} to --mode coordinates "
        f"(the OFP bases); --mode {detail.mode} carries the source's detail in local frames, "
        f"with no OFP basis: drop {'it' if len(named) == 1 else 'them'}"))
    prepared = prepare_pair(args, pair, planned)
    with stage(f"detail transfer ({detail.mode})"):
        moved = transfer_detail(pair.source, pair.target, correspondence=prepared.correspondence,
                                mode=detail.mode, band=detail.band, amount=detail.amount,
                                options=common.basis_options(args),
                                bases=prepared.bases or (prepared.eig_1, prepared.eig_2))
    write_geometry(args.output, pair.in_target_units(moved), protect=pair.inputs)
    what = detail.mode if detail.mode == "coordinates" else (
        f"{detail.mode}, " + ("calibrated" if detail.band is None else f"band {detail.band}"))
    report([f"{args.source} -> {args.target}: detail ({what})", f"wrote {args.output}"])
    return 0
