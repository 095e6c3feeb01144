"""``o3d-ofp transfer``: move a signal (colors, a texture, coordinates, any array) to a target."""

from __future__ import annotations

import argparse

from ._common import CLOUD_OUT, MESH_OUT, UsageError, check_output, report, stage
from ._pair import add_pair_options, bases_for_pair, estimate_or_use_map, read_pair
from ._signal import read_signal, write_result

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("transfer", help="transfer a signal from a source to a target shape")
    add_pair_options(p, preset="ours")
    p.add_argument(
        "--signal",
        default="colors",
        help="colors, texture, xyz or FILE.npy of the source (default colors)",
    )
    p.add_argument("--texture", help="texture image for --signal texture (default: the mesh's)")
    p.add_argument(
        "-o", "--output", required=True, help="colored target (mesh/cloud), or .npy values"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read, match (or read the map), transfer, write."""
    from ..workflows.pipeline import transfer_function

    check_output(args.output, (*MESH_OUT, *CLOUD_OUT, ".npy"), inputs=(args.source, args.target))
    pair = read_pair(args)
    f, kind = read_signal(pair.source, pair.V1, args.source, args.signal, args.texture)
    B1, B2, eig_1, eig_2 = bases_for_pair(args, pair)
    corr = estimate_or_use_map(args, pair, eig_1, eig_2)
    if corr.n_source != pair.V1.shape[0]:
        raise UsageError("the map does not belong to these shapes")
    with stage("transfer"):
        g = transfer_function(f, eig_1, eig_2, p2p_21=corr.p2p_21, bases=(B1, B2))
    written = write_result(args.output, pair.target, g, kind)
    report(
        [
            f"{args.source} -> {args.target}: {B1.size} -> {B2.size} basis functions, map "
            f"{corr.method}",
            "wrote " + ", ".join(written),
        ]
    )
    return 0
