"""``o3d-ofp detail``: give the target the source's geometric detail."""

from __future__ import annotations

import argparse

from ._common import CLOUD_OUT, MESH_OUT, UsageError, check_output, report, stage, tol_options
from ._pair import add_pair_options, bases_for_pair, estimate_or_use_map, read_pair
from ._types import positive_int

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("detail", help="give the target the source's geometric detail")
    add_pair_options(p, preset="ours*")
    p.add_argument(
        "--mode",
        choices=("add", "replace"),
        default="add",
        help="add: source detail along the target's normals; replace: transferred coordinates "
        "(the paper's Fig. 13) (add)",
    )
    p.add_argument("--k-low", type=positive_int, help="low-pass size for --mode add (k1)")
    p.add_argument("-o", "--output", required=True, help="displaced target")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read, match (or read the map), move the target's vertices, write."""
    from ..boundary.api import transfer_detail
    from ..boundary.io import write_geometry

    check_output(args.output, (*MESH_OUT, *CLOUD_OUT), inputs=(args.source, args.target))
    if args.k_low is not None and args.k_low > (args.k1 or 29):
        raise UsageError(f"--k-low {args.k_low} must not exceed --k1 ({args.k1 or 29})")
    pair = read_pair(args)
    if pair.F1 is None:
        raise UsageError(f"{args.source}: the detail source must be a triangle mesh")
    B1, B2, eig_1, eig_2 = bases_for_pair(args, pair)
    corr = estimate_or_use_map(args, pair, eig_1, eig_2)
    with stage(f"detail transfer ({args.mode})"):
        moved = transfer_detail(
            pair.source,
            pair.target,
            mode=args.mode,
            k1=B1.k,
            k2=B2.k,
            order=args.order,
            **tol_options(args),
            p2p_21=corr.p2p_21,
            bases=(B1, B2),
            eigenbases=(eig_1, eig_2),
            k_low=args.k_low,
        )
    write_geometry(args.output, moved)
    report([f"{args.source} -> {args.target}: detail ({args.mode})", f"wrote {args.output}"])
    return 0
