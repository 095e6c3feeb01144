"""The ``o3d-ofp`` parser and entry point: global flags, logging, exit codes.

Exit codes: 0 success; 2 bad usage or bad input (one line on stderr naming the file or the
flag, no traceback); 3 a suspect map under ``--strict`` (nothing written); 1 an internal
error (``-v`` adds the traceback). Long stages log at INFO on stderr (``-q`` silences
everything but warnings and errors); a progress bar is drawn when stderr is a terminal.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import re
import sys
import warnings
from collections.abc import Iterator, Sequence
from typing import Any

from ..core._version import __version__
from ..core._warnings import OFPWarning, warnings_logged
from ..core.wording import text_of
from . import approximate, basis, demo, detail, filter, render, transfer
from ._common import OUT, UsageError, error_text
from ._pair import SUSPECT_EXIT, SuspectMap
from ._progress import ENABLED

__all__ = ["build_parser", "main"]

logger = logging.getLogger(__name__)

COMMANDS = (basis, approximate, transfer, detail, filter, render, demo)


class _Shown(logging.Filter):
    """The log in the command line's words: what is shown, and how it is worded.

    A record carrying a Said (``record.said``, see :func:`o3d_ofp.core._warnings.warn`) is
    worded for flags. A run over one pair (``OUT.one_pair``) says each warning once (the
    library may say one again, of a map it is given twice) and, with ``quiet_reports``, leaves
    out the records of the map's quality report, which it prints (a collection's records keep
    the lines of each target, and a warning of each, in the log).
    """

    def __init__(self, quiet_reports: bool) -> None:
        super().__init__()
        self.quiet_reports, self.seen = quiet_reports, set()

    def filter(self, record: logging.LogRecord) -> bool:
        if self.quiet_reports and getattr(record, "quality_report", False) and OUT.one_pair:
            return False
        if getattr(record, "said", None) is not None:
            record.msg, record.args = text_of(record.said, cli=True), None
        text = record.getMessage()
        fresh = record.levelno < logging.WARNING or not OUT.one_pair or text not in self.seen
        self.seen.add(text)
        return fresh


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line (and a pointer to --help)."""

    def error(self, message: str) -> Any:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of every command."""
    parser = _Parser(prog="o3d-ofp", description="Orthogonalized Fourier Polynomials (Maggioli et "
                     "al., EG 2021) for Open3D: bases, approximation, filtering and transfer of "
                     "signals between shapes.")  # fmt: skip
    a = parser.add_argument
    a("-v", "--verbose", action="count", default=0, help="-v: an internal error's traceback; -vv: "
      "the debug log too (every step's details; the long stages are logged without -v)")
    a("--version", action="version", version=f"%(prog)s {__version__}")
    a("-q", "--quiet", action="store_true", help="print nothing but warnings and errors (files "
      "are written)")  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
    # -q / -v also after the command (o3d-ofp transfer ... -q); there they override the
    # values given before it (SUPPRESS: absent flags leave those alone). A word such as "-1:40"
    # is a value, not an option (no option starts with a dash and a digit; argparse alone takes
    # only plain negative numbers for values): "--landmarks -1:40" reaches the option's own
    # check, which says what is wrong.
    hidden = {"default": argparse.SUPPRESS, "help": argparse.SUPPRESS}
    for command_parser in sub.choices.values():
        command_parser._negative_number_matcher = re.compile(r"^-\d")
        command_parser.add_argument("-v", "--verbose", action="count", **hidden)
        command_parser.add_argument("-q", "--quiet", action="store_true", **hidden)
    return parser


@contextlib.contextmanager
def _logging_to_stderr(level: int) -> Iterator[None]:
    """Send the package's log records to the current stderr for the duration of a command.

    Above DEBUG, the records of a map's quality report are left out where the command prints
    the report (:data:`o3d_ofp.workflows.quality.QUALITY_RECORD`); see :class:`_Shown`.
    """
    root, handler = logging.getLogger("o3d_ofp"), logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("o3d-ofp: %(message)s"))
    handler.addFilter(_Shown(quiet_reports=level > logging.DEBUG))
    saved, root.propagate = (root.level, root.propagate), False
    root.addHandler(handler)
    root.setLevel(level)
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.setLevel(saved[0])  # (setLevel: the loggers' cached levels are cleared)
        root.propagate = saved[1]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit code: 0 success, 2 bad usage or input, 3 suspect map under ``--strict``,
        1 a missing dependency, a failed write or connection during the run, or an
        internal error.
    """
    parser = build_parser()
    words = list(sys.argv[1:] if argv is None else argv)
    try:
        args, extra = parser.parse_known_args(words)
        if extra:  # said by the parser they were given to: its name and its --help
            before = words[: words.index(args.command)] if args.command in words else []
            sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            said = parser if any(e in before for e in extra) else sub.choices[args.command]
            said.error(f"unrecognized arguments: {' '.join(extra)}")
    except SystemExit as exc:  # argparse exits 2 on bad usage, 0 on --help
        return int(exc.code or 0)
    # -q: warnings stay (a suspect map or a refused option is said even then)
    level = logging.WARNING if args.quiet else logging.DEBUG if args.verbose > 1 else logging.INFO
    OUT.quiet, OUT.args, OUT.renamed, OUT.one_pair = bool(args.quiet), args, {}, False
    ENABLED.on = not args.quiet
    # OFPWarnings repeat what the log already prints (logged at WARNING here).
    with _logging_to_stderr(level), warnings.catch_warnings(), warnings_logged():
        warnings.simplefilter("ignore", OFPWarning)
        try:
            return args.func(args)
        except SuspectMap as exc:
            code = SUSPECT_EXIT
            kept = getattr(args, "save_landmarks", None)  # written first, not to lose picks
            written = "nothing written" + (f" but {kept} (--save-landmarks)" if kept else "")
            said = f"error: the map is suspect (--strict): {exc}; {written}"
        except (UsageError, ValueError, TypeError, FileNotFoundError, FileExistsError,
                IsADirectoryError, PermissionError) as exc:  # fmt: skip
            code, said = 2, f"error: {error_text(exc)}"
        except (ImportError, ConnectionError) as exc:
            code, said = 1, f"error: {error_text(exc)}"
        except OSError as exc:  # a full disk, a file system gone read-only during the run
            where = f" ({exc.filename})" if exc.filename else ""
            code, said = 1, f"error: cannot read or write{where}: {exc.strerror or exc}"
        except KeyboardInterrupt:
            code, said = 130, "interrupted"
        except Exception as exc:
            if args.verbose:
                logger.exception("internal error")
            code, said = 1, f"internal error: {type(exc).__name__}: {exc}"
    sys.stderr.write(f"o3d-ofp {args.command}: {said}\n")
    return code
