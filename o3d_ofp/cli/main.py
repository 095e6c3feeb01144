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
    worded for flags; each warning is said once per command (the library may say one again,
    of a map it is given twice); with ``quiet_reports``, a map's quality report is left out
    when the command prints it (a run over one pair, ``OUT.reports_quality``; a collection's
    records keep the lines of each target in the log).
    """

    def __init__(self, quiet_reports: bool) -> None:
        super().__init__()
        self.quiet_reports, self.seen = quiet_reports, set()

    def filter(self, record: logging.LogRecord) -> bool:
        if self.quiet_reports and getattr(record, "quality_report", False) and OUT.reports_quality:
            return False
        if getattr(record, "said", None) is not None:
            record.msg, record.args = text_of(record.said, cli=True), None
        text = record.getMessage()
        fresh = record.levelno < logging.WARNING or text not in self.seen
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
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="-v: an internal error shows its traceback; -vv: the debug log too "
                        "(every step's details; the long stages are logged without -v)")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="print nothing but warnings and errors (files are written)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
    # -q / -v also after the command (o3d-ofp transfer ... -q); there they override the
    # values given before it (SUPPRESS: absent flags leave those alone).
    for command_parser in sub.choices.values():
        command_parser.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                                    help=argparse.SUPPRESS)  # fmt: skip
        command_parser.add_argument("-q", "--quiet", action="store_true",
                                    default=argparse.SUPPRESS, help=argparse.SUPPRESS)
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
    saved = (root.level, root.propagate)
    root.addHandler(handler)
    root.setLevel(level)
    root.propagate = False
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.level, root.propagate = saved


#: A value argparse reads as an option: a dash, a digit, then more than a plain number has.
_DASH_VALUE = re.compile(r"-\d")
_NUMBER = re.compile(r"-?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def _value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Return the long options of ``parser`` and of its commands that take a value."""
    found = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found |= _value_options(sub)
        elif action.nargs != 0:
            found |= {o for o in action.option_strings if o.startswith("--")}
    return found


def joined_dash_values(words: Sequence[str], options: set[str]) -> list[str]:
    """Join a long option of ``options`` and a value such as ``-1:40`` (``--landmarks=-1:40``).

    argparse takes a word that starts with a dash for an option unless it is a plain number,
    so ``--landmarks -1:40`` stopped at "expected one argument" (a trial); joined, the value
    reaches the option's own check, which says what is wrong with it. No option starts with
    a dash and a digit; a flag that takes no value (``--strict``) is not joined.
    """
    out: list[str] = []
    for word in words:
        last = out[-1] if out else ""
        if _DASH_VALUE.match(word) and not _NUMBER.fullmatch(word) and last in options:
            out[-1] = f"{last}={word}"
        else:
            out.append(word)
    return out


def _parse(parser: argparse.ArgumentParser, words: list[str]) -> argparse.Namespace:
    """Parse the words; unknown ones are said by the parser they were given to."""
    args, extra = parser.parse_known_args(words)
    if extra:  # said by the parser they were given to: its name and its --help
        before = words[: words.index(args.command)] if args.command in words else []
        if any(e in before for e in extra):
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        sub.choices[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    return args


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
    try:
        args = _parse(parser, joined_dash_values(sys.argv[1:] if argv is None else argv,
                                                 _value_options(parser)))  # fmt: skip
    except SystemExit as exc:  # argparse exits 2 on bad usage, 0 on --help
        return int(exc.code or 0)
    # -q: warnings stay (a suspect map or a refused option is said even then)
    level = logging.WARNING if args.quiet else logging.DEBUG if args.verbose > 1 else logging.INFO
    prog = f"o3d-ofp {args.command}"
    OUT.quiet, OUT.args, OUT.renamed, OUT.reports_quality = bool(args.quiet), args, {}, False
    ENABLED.on = not args.quiet
    # OFPWarnings repeat what the log already prints (logged at WARNING here).
    with _logging_to_stderr(level), warnings.catch_warnings(), warnings_logged():
        warnings.simplefilter("ignore", OFPWarning)
        try:
            return args.func(args)
        except SuspectMap as exc:
            code = SUSPECT_EXIT
            said = f"error: the map is suspect (--strict): {exc}; nothing written"
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
    sys.stderr.write(f"{prog}: {said}\n")
    return code
