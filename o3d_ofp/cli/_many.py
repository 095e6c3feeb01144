"""Several targets at once (``transfer``/``detail`` TARGET... -o DIR) and ``basis`` of a collection.

One source onto a list or folder of targets runs on the collection engine
(:mod:`o3d_ofp.collections`, on Dask): the source's bases are computed once, each target is a
task, a failing target is reported and never stops the others, every result is written
atomically to ``DIR/<target file name>``, and a rerun skips targets whose output is newer than
both inputs. The summary is printed (one line per target) and written as ``DIR/summary.csv``
and ``DIR/summary.json``; the exit code is 1 when any target failed.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping, Sequence
from typing import Any

from ..core.wording import text_of
from ._common import OUT, UsageError, report
from ._progress import ENABLED
from ._types import nonnegative_int

__all__ = [
    "add_collection_options",
    "check_single",
    "is_collection",
    "refuse_flags",
    "report_records",
    "run_transfers",
]

#: Flags of the two-shape commands that make no sense for a collection, and why.
PAIR_ONLY = {
    "landmarks": "--landmarks (vertex pairs belong to one pair of shapes)",
    "save_map": "--save-map (one map per pair)",
    "basis_1": "--basis-1 (use --cache DIR)",
    "basis_2": "--basis-2 (use --cache DIR)",
    "align": "--align (--map closest is for one pair)",
    "save_landmarks": "--save-landmarks (landmarks belong to one pair of shapes)",
    "partial": "--partial (for one pair of shapes)",
    "via_basis": "--via-basis (for one pair of shapes)",
    "pull_back": "--pull-back (for one pair of shapes)",
    "target_scale": "--target-scale (for one pair of shapes)",
}


def add_collection_options(
    p: argparse.ArgumentParser,
    *,
    description: str = (
        "give several targets or a folder of them; -o is then a folder (created if missing), "
        "with summary.csv and summary.json"
    ),
) -> None:
    """Add the flags of runs over several shapes (``description``: what such a run writes)."""
    g = p.add_argument_group("several shapes", description)
    g.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run on this Dask cluster (default: a local cluster, one worker process per core)",
    )
    g.add_argument(
        "--workers",
        type=nonnegative_int,
        help="worker processes of the local cluster (default: the cores; 0: in this process)",
    )
    g.add_argument(
        "--force",
        action="store_true",
        help="redo targets whose output is newer than both inputs (default: skip them)",
    )


def is_collection(targets: Sequence[str]) -> bool:
    """Whether a command runs over several shapes: several targets, or a folder of them.

    One target file is the two-shape form, whose ``-o`` names a file (an existing folder is
    refused as such).
    """
    return len(targets) > 1 or any(os.path.isdir(t) for t in targets)


def check_single(args: argparse.Namespace) -> None:
    """Refuse the collection flags on a run over one pair of shapes."""
    for name, flag in (("scheduler", "--scheduler"), ("workers", "--workers")):
        if getattr(args, name, None) is not None:
            raise UsageError(f"{flag} applies to several targets (TARGET... or a folder)")
    if getattr(args, "force", False):
        raise UsageError("--force applies to several targets (TARGET... or a folder)")
    OUT.reports_quality = True  # one pair: its quality report is printed, not logged


def refuse_flags(args: argparse.Namespace, flags: Mapping[str, str]) -> None:
    """Refuse flags given (not None / not False) that a collection run cannot honour."""
    for name, flag in flags.items():
        value = getattr(args, name, None)
        if value not in (None, False):
            raise UsageError(f"{flag} does not apply to several targets")


def _check_scheduler(address: str) -> None:
    """Refuse, before any work, a scheduler address where nothing listens."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        port = parts.port
    except ValueError:
        port = None
    schemes = ("tcp", "tls", "ws", "wss", "ucx")
    if parts.scheme not in schemes or not parts.hostname or port is None:
        raise UsageError(f"--scheduler {address}: expected tcp://HOST:PORT (or tls, ws, wss, ucx)")
    if parts.scheme == "ucx":  # no plain socket to try: Dask will say
        return
    try:
        socket.create_connection((parts.hostname, port), timeout=5).close()
    except OSError as exc:
        raise UsageError(
            f"--scheduler {address}: nothing answers there ({exc.strerror or exc}); start the "
            "scheduler (dask scheduler) or leave --scheduler out for a local cluster"
        ) from exc


def _check_output_dir(path: str) -> None:
    from ._common import CLOUD_OUT, MESH_OUT, check_writable_folder

    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"-o {path}: is a file; with several targets -o names a folder")
    ext = os.path.splitext(path)[1].lower()
    if not os.path.exists(path) and ext in (*MESH_OUT, *CLOUD_OUT, ".npy"):
        raise UsageError(
            f"-o {path}: with several targets -o names a folder (the results keep the targets' "
            f"names); {ext} looks like one output file"
        )
    if os.path.isdir(path):  # written into: it must be writable
        check_writable_folder(path, path)
        return
    check_writable_folder(os.path.dirname(os.path.abspath(path)), path)  # it is made there


def report_records(records: Sequence[Any]) -> int:
    """Print one line per shape and a count; return 1 when any failed, else 0.

    With ``-q`` nothing is printed here: the failures and the suspect maps were logged as
    warnings, which ``-q`` keeps (each named: the exit code 1 alone would not say which shapes
    failed, nor why).
    """
    lines = []
    for r in records:
        if r.status == "failed":
            lines.append(f"failed   {r.name}: {text_of(r.error, cli=True)}")
        elif r.status == "skipped":
            sus = " (its map was SUSPECT when it was made: see the summary)" if r.suspect else ""
            lines.append(f"skipped  {r.name}: up to date ({r.output}){sus}")
        else:
            cov = (
                ""
                if r.coverage != r.coverage
                else f", map coverage {r.coverage:.2f} of the source's vertices"
            )
            sus = " (SUSPECT map: see its warning on stderr and the summary)" if r.suspect else ""
            where = f" -> {r.output}" if r.output else ""
            lines.append(f"ok       {r.name}: {r.seconds:.1f} s{cov}{sus}{where}")
    counts = {s: sum(r.status == s for r in records) for s in ("ok", "failed", "skipped")}
    lines.append(", ".join(f"{n} {s}" for s, n in counts.items()))
    report(lines)
    return 1 if counts["failed"] else 0


def run_transfers(args: argparse.Namespace, *, kind: str, options: Mapping[str, Any]) -> int:
    """Run one source onto every target of ``args.target`` (files and folders) into ``-o DIR``.

    ``options``: the command's own keywords of :func:`o3d_ofp.transfer_many`; the map, basis
    and run flags are added here (those not given are left to its defaults).
    """
    from ..collections import transfer_many, write_summary
    from ._common import check_cache_dir

    _check_output_dir(args.output)
    check_cache_dir(args.cache)
    _check_cluster(args)
    if args.map not in ("estimate", "identity"):
        raise UsageError(
            f"--map {args.map}: with several targets the map is 'estimate' or 'identity'"
        )
    if not os.path.isfile(args.source):
        raise UsageError(f"{args.source}: no such source file")
    for target in args.target:  # a typo is said before any work (a trial's ran every other)
        if not os.path.exists(target):
            raise UsageError(f"{target}: no such target file or folder")
    given = {"k1": args.k1, "k2": args.k2, "order": args.order, "tol": args.tol,
             "preset": None if args.tol is not None else args.preset, **options}  # fmt: skip
    records = transfer_many(
        args.source, args.target, kind=kind, client=args.scheduler, output_dir=args.output,
        cache_dir=args.cache, workers=args.workers, skip_existing=not args.force,
        progress=ENABLED.on, map=args.map, components=args.components, strict=args.strict,
        **{name: value for name, value in given.items() if value is not None},
    )  # fmt: skip
    csv_path, json_path = write_summary(records, args.output)
    code = report_records(records)
    report([f"summary: {csv_path}, {json_path}"])
    return code


def _check_cluster(args: argparse.Namespace) -> None:
    """Refuse, before any work, a cluster run without Dask, or a scheduler nobody answers at."""
    if args.scheduler or args.workers != 0:  # a cluster: Dask must be there, said first
        import importlib.util

        if importlib.util.find_spec("distributed") is None:
            raise UsageError(
                "several targets run on a Dask cluster, and Dask is not installed: pip install "
                "'dask[distributed]' (from a clone of o3d_ofp: pip install -e '.[dask]'), or give "
                "--workers 0 to run them one after the other here"
            )
    if args.scheduler:
        _check_scheduler(args.scheduler)
