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
import contextlib
import dataclasses
import functools
import importlib.util
import os
import socket
from collections.abc import Mapping, Sequence
from typing import Any
from urllib.parse import urlsplit

from ..collections import transfer_many, write_summary
from ..core.wording import text_of
from . import _common as common
from ._common import UsageError, nonnegative_int, report
from ._progress import ENABLED

#: Flags of the two-shape commands that make no sense for a collection, and why.
PAIR_ONLY = {
    "landmarks": "--landmarks (vertex pairs belong to one pair of shapes)",
    "save_map": "--save-map (one map per pair)", "basis_1": "--basis-1 (use --cache DIR)",
    "basis_2": "--basis-2 (use --cache DIR)", "align": "--align (--map closest is for one pair)",
    "save_landmarks": "--save-landmarks (landmarks belong to one pair of shapes)",
    **{name: f"--{name.replace('_', '-')} (for one pair of shapes)"
       for name in ("partial", "via_basis", "pull_back", "target_scale")},
}  # fmt: skip


def add_collection_options(p: argparse.ArgumentParser, *, description: str = (
    "give several targets or a folder of them; -o is then a folder (created if missing), with "
    "summary.csv and summary.json")) -> None:  # fmt: skip
    """Add the flags of runs over several shapes (``description``: what such a run writes)."""
    g = p.add_argument_group("several shapes", description)
    g.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask cluster "
                   "(default: a local cluster, one worker process per core)")
    g.add_argument("--workers", type=nonnegative_int, help="worker processes of the local cluster "
                   "(default: the cores; 0: in this process)")
    g.add_argument("--force", action="store_true", help="redo targets whose output is newer than "
                   "both inputs (default: skip them)")  # fmt: skip


def single(args: argparse.Namespace, name: str) -> bool:
    """Whether a command runs over one pair (or one shape); its collection flags refused then.

    Several shapes (``args.<name>``), or a folder of them, are a collection; one file is the
    two-shape form, whose ``-o`` names a file (an existing folder is refused as such):
    ``args.<name>`` is then that file.
    """
    shapes = getattr(args, name)
    if len(shapes) > 1 or any(os.path.isdir(t) for t in shapes):
        return False
    setattr(args, name, shapes[0])
    for flag in ("--scheduler", "--workers", "--force"):
        if getattr(args, flag[2:]) not in (None, False):
            raise UsageError(f"{flag} applies to several targets (TARGET... or a folder)")
    common.OUT.one_pair = True  # its quality report is printed, not logged; a warning said once
    return True


def _check_scheduler(address: str) -> None:
    """Refuse, before any work, a scheduler address where nothing listens."""
    parts, port = urlsplit(address if "://" in address else f"tcp://{address}"), None
    with contextlib.suppress(ValueError):  # a port that is not a number
        port = parts.port
    if parts.scheme not in ("tcp", "tls", "ws", "wss", "ucx") or not parts.hostname or not port:
        raise UsageError(f"--scheduler {address}: expected tcp://HOST:PORT (or tls, ws, wss, ucx)")
    if parts.scheme == "ucx":  # no plain socket to try: Dask will say
        return
    try:
        socket.create_connection((parts.hostname, port), timeout=5).close()
    except OSError as exc:
        raise UsageError(f"--scheduler {address}: nothing answers there ({exc.strerror or exc}); "
                         "start the scheduler (dask scheduler) or leave --scheduler out for a "
                         "local cluster") from exc  # fmt: skip


def _check_run(args: argparse.Namespace) -> None:
    """Refuse, before any work, a bad ``-o DIR``, a cluster without Dask, a bad scheduler."""
    path, ext = args.output, os.path.splitext(args.output)[1].lower()
    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"-o {path}: is a file; with several targets -o names a folder")
    if not os.path.exists(path) and ext in (*common.GEOMETRY_OUT, ".npy"):
        raise UsageError(f"-o {path}: with several targets -o names a folder (the results keep the "
                         f"targets' names); {ext} looks like one output file")  # fmt: skip
    common.check_folder_to_make(path, "-o")  # written into, or made in its nearest folder
    common.check_folder_to_make(args.cache, "--cache")
    if (args.scheduler or args.workers != 0) and importlib.util.find_spec("distributed") is None:
        raise UsageError("several targets run on a Dask cluster, and Dask is not installed: pip "
                         "install 'dask[distributed]' (from a clone of o3d_ofp: pip install -e "
                         "'.[dask]'), or give --workers 0 to run them one after the other here")
    if args.scheduler:
        _check_scheduler(args.scheduler)


def report_records(records: Sequence[Any]) -> int:
    """Print one line per shape and a count; return 1 when any failed, else 0.

    With ``-q`` nothing is printed here: the failures and the suspect maps were logged as
    warnings, which ``-q`` keeps (each named: the exit code 1 alone would not say which shapes
    failed, nor why).
    """
    counts = {s: sum(r.status == s for r in records) for s in ("ok", "failed", "skipped")}
    report([*map(_line, records), ", ".join(f"{n} {s}" for s, n in counts.items())])
    return 1 if counts["failed"] else 0


def _line(r: Any) -> str:
    """Return the result line of one shape's record."""
    if r.status == "failed":
        return f"failed   {r.name}: {text_of(r.error, cli=True)}"
    if r.status == "skipped":
        sus = " (its map was SUSPECT when it was made: see the summary)" if r.suspect else ""
        return f"skipped  {r.name}: up to date ({r.output}){sus}"
    cov = "" if r.coverage != r.coverage else (
        f", map coverage {r.coverage:.2f} of the source's vertices")  # fmt: skip
    sus = " (SUSPECT map: see its warning on stderr and the summary)" if r.suspect else ""
    where = f" -> {r.output}" if r.output else ""
    return f"ok       {r.name}: {r.seconds:.1f} s{cov}{sus}{where}"


def run_transfers(args: argparse.Namespace, *, kind: str, options: Mapping[str, Any]) -> int:
    """Run one source onto every target of ``args.target`` (files and folders) into ``-o DIR``.

    ``options``: the command's own keywords of :func:`o3d_ofp.transfer_many`; the map, basis
    and run flags are added here (those not given are left to its defaults). The flags for
    one pair (:data:`PAIR_ONLY`) are refused.
    """
    common.refuse(*((getattr(args, name, None) not in (None, False), f"{flag} does not apply to "
                     "several targets") for name, flag in PAIR_ONLY.items()))  # fmt: skip
    _check_run(args)
    common.refuse(  # a typo in a target's name is said before any work
        (args.map not in ("estimate", "identity"), f"--map {args.map}: with several targets the "
         "map is 'estimate' or 'identity'"),
        (not os.path.isfile(args.source), f"{args.source}: no such source file"),
        *((not os.path.exists(t), f"{t}: no such target file or folder") for t in args.target),
    )  # fmt: skip
    given = {**common.basis_flags(args), **options}
    records = transfer_many(args.source, args.target, kind=kind, client=args.scheduler,
                            output_dir=args.output, cache_dir=args.cache, workers=args.workers,
                            skip_existing=not args.force, progress=ENABLED.on, map=args.map,
                            components=args.components, strict=args.strict,
                            **{name: value for name, value in given.items() if value is not None})
    words = functools.partial(text_of, cli=True)  # what was said of each target, for flags
    records = [dataclasses.replace(r, error=words(r.error), warnings=tuple(map(words, r.warnings)),
                                   notes=tuple(map(words, r.notes))) for r in records]
    csv_path, json_path = write_summary(records, args.output)
    code = report_records(records)
    report([f"summary: {csv_path}, {json_path}"])
    return code
