"""What the commands share: reading inputs, checking outputs, bases, maps, result lines.

Every check that can fail is made before the expensive work, and every message names the
file or the flag.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import glob
import logging
import math
import os
import re
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

__all__ = [
    "CLOUD_OUT",
    "MESH_HELP",
    "MESH_OUT",
    "UsageError",
    "about",
    "add_basis_options",
    "basis_for",
    "check_cache_dir",
    "check_folder_to_make",
    "check_job_memory",
    "check_output",
    "eig_options",
    "eigenbases_of",
    "in_flags",
    "load_npy",
    "read_shape",
    "report",
    "same_file",
    "stage",
    "tol_options",
]

logger = logging.getLogger(__name__)

MESH_HELP = "mesh or point cloud (any format Open3D reads: PLY, OBJ, OFF, STL, GLB, ...)"
MESH_OUT = (".ply", ".obj", ".off", ".stl", ".glb", ".gltf")
CLOUD_OUT = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")


class UsageError(Exception):
    """Bad input or arguments: reported in one line, exit code 2."""


class _Output:
    """The command's result lines on stdout; nothing with ``-q``.

    ``reports_quality``: the command prints a map's quality report itself (a run over one
    pair), so the library's own log record of it is left out of stderr (``main``).
    """

    quiet = False
    reports_quality = False

    def write(self, text: str) -> None:
        if not self.quiet:
            sys.stdout.write(text)


OUT = _Output()


#: Library keywords that error messages mention, and the flags that set them.
KEYWORD_FLAGS = {
    "components='largest'": "--components largest",
    "components='auto'": "--components auto",
    "components='error'": "--components error",
    "landmarks=[[source, target], ...] / ": "",
    ", or ofp.transfer_colors(..., landmarks=...))": ")",
    "colormap must be one of": "--colormap must be one of",
}


#: Library messages name a keyword and its flag together, "align=True (--align)" or
#: "partial=True / --partial" (either order): the command line says the flag alone.
_KEYWORD_THEN_FLAG = re.compile(r"\b[a-z_]+=(?:[^\s()/]|\(\))* \((--[a-z][^)]*)\)")
_KEYWORD_OR_FLAG = re.compile(r"\b[a-z_]+=(?:[^\s()/,;]|\(\))* / (?=--[a-z])")
_FLAG_OR_KEYWORD = re.compile(r"(--[a-z][a-z-]*(?: [A-Z]+)?) / [a-z_]+=(?:\.\.\.|[^\s),;]*)")


#: Library messages tell a target in other units to be scaled with Open3D: the command line
#: has a flag for it.
_TARGET_SCALE = re.compile(r"(?:Open3D's )?target\.scale\(([^,()]+), center=\(0, 0, 0\)\)")


def in_flags(message: str) -> str:
    """Say the command line's flags where a library message names its keywords."""
    for keyword, flag in KEYWORD_FLAGS.items():
        message = message.replace(keyword, flag)
    message = _TARGET_SCALE.sub(lambda m: f"--target-scale {m.group(1)}", message)
    message = _KEYWORD_THEN_FLAG.sub(lambda m: m.group(1), message)
    message = _KEYWORD_OR_FLAG.sub("", message)
    return _FLAG_OR_KEYWORD.sub(lambda m: m.group(1), message)


def report(lines: Sequence[str]) -> None:
    """Print result lines (silenced by ``-q``), with the flags the library's messages name."""
    for line in lines:
        OUT.write(in_flags(line) + "\n")


@contextlib.contextmanager
def stage(what: str) -> Iterator[None]:
    """Log a long stage at INFO: its start and its duration."""
    logger.info("%s ...", what)
    t0 = time.perf_counter()
    yield
    logger.info("%s: done in %.2f s", what, time.perf_counter() - t0)


# --------------------------------------------------------------------------- inputs


def read_shape(path: str) -> tuple[Any, np.ndarray, np.ndarray | None]:
    """(geometry, vertices, faces) of a mesh or cloud file; one-line errors naming the file."""
    from ..boundary.convert import geometry_to_arrays, require_open3d
    from ..boundary.io import read_geometry

    require_open3d()
    if not os.path.exists(path):
        raise UsageError(f"{path}: no such file")
    if os.path.isdir(path):
        raise UsageError(f"{path}: is a directory, not a mesh file")
    try:
        geometry = read_geometry(path)
        V, F = geometry_to_arrays(geometry)
    except ValueError as exc:
        raise UsageError(f"{path}: cannot read a mesh or point cloud ({exc})") from exc
    return geometry, V, F


def load_npy(path: str, what: str, *, flag: str) -> np.ndarray:
    """Load a real-valued ``.npy`` array; one-line errors name the file and the flag."""
    if not os.path.isfile(path):
        raise UsageError(f"{flag} {path}: no such file")
    with open(path, "rb") as fh:
        magic = fh.read(6)
    if magic != b"\x93NUMPY":  # NumPy's own message speaks of pickles for any other file
        raise UsageError(
            f"{flag} {path}: not a NumPy .npy file ({what}): it does not start with the .npy "
            "header (write it with numpy.save)"
        )
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise UsageError(f"{flag} {path}: not a NumPy .npy file ({what}): {exc}") from exc
    if not isinstance(arr, np.ndarray):
        raise UsageError(f"{flag} {path}: expected one array ({what}), got an archive")
    if np.iscomplexobj(arr) or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_):
        raise UsageError(f"{flag} {path}: must hold real numbers ({what}); got dtype {arr.dtype}")
    return arr


def tol_options(args: argparse.Namespace) -> dict[str, Any]:
    """``tol``/``preset`` keywords from ``--tol``/``--preset``."""
    if args.tol is not None:
        return {"tol": args.tol, "preset": None}
    return {"tol": None, "preset": args.preset}


def eig_options(args: argparse.Namespace) -> dict[str, Any]:
    """Keywords of the eigenbasis that the flags set."""
    return {"components": args.components}


def eigenbases_of(
    args: argparse.Namespace, shapes: Sequence[tuple[str, Any, Any, int]], *, clamp_k: bool
) -> list[Any]:
    """Eigenbases of ``(path, V, F, k)`` shapes, side by side; a refusal names its file."""
    from ..core.spectrum import eigenbasis
    from ..workflows.eigenbases import eigenbasis_bytes, run_per_shape

    def job(path: str, V: Any, F: Any, k: int) -> Any:
        with about(path):
            return eigenbasis(V, F, k=k, clamp_k=clamp_k, **eig_options(args))

    return run_per_shape(
        [functools.partial(job, *shape) for shape in shapes],
        [V.shape[0] for _, V, _, _ in shapes],
        [eigenbasis_bytes(V.shape[0], k) for _, V, _, k in shapes],
        what="eigenbases",
    )


def written_beside(path: str) -> list[str]:
    """Existing files that writing ``path`` may replace besides it.

    An OBJ's ``.mtl`` and texture images (Open3D names them ``<stem>_<i>.<ext>``), a glTF's
    ``.bin``. The writer refuses them too (``write_geometry(protect=...)``); naming them here
    lets a command refuse before any work.
    """
    stem, ext = os.path.splitext(path)
    ext = ext.lower()
    if ext == ".obj":
        return [stem + ".mtl", *sorted(glob.glob(glob.escape(stem) + "_[0-9]*.*"))]
    if ext == ".gltf":
        return [stem + ".bin", *sorted(glob.glob(glob.escape(stem) + "_[0-9]*.*"))]
    return []


def check_output(
    path: str,
    allowed: Sequence[str],
    *,
    inputs: Sequence[str | None] = (),
    flag: str = "-o",
    side: Sequence[str] = (),
) -> None:
    """Refuse a bad output path before any work.

    Wrong extension, missing folder, a directory, or one of the inputs (which would be
    overwritten), also through a file written beside it (``side``, and those of
    :func:`written_beside`). ``inputs`` may hold flag values that are not files (``None``,
    ``"colors"``): only existing files are compared.
    """
    ext = os.path.splitext(path)[1].lower()
    if os.path.isdir(path) or path.endswith(("/", os.sep)):
        raise UsageError(
            f"{flag} {path}: is a directory{'' if os.path.isdir(path) else ' name'}; give a file "
            "name (a folder is the output of several targets)"
        )
    if ext not in allowed:
        raise UsageError(
            f"{flag} {path}: the output must end with one of {', '.join(dict.fromkeys(allowed))}"
        )
    folder = os.path.dirname(os.path.abspath(path))
    check_writable_folder(folder, path, flag=flag)
    for other in (*side, *written_beside(path)):  # (found by a trial only after the work)
        if os.path.isdir(other):
            raise UsageError(
                f"{flag} {path}: writing it may also write {other} (a file Open3D writes "
                "beside it), which is a folder; choose another output name"
            )
    for source in inputs:  # names that are not files ("colors", "estimate") are skipped
        if not (isinstance(source, str) and os.path.exists(source)):
            continue
        if same_file(path, source):
            raise UsageError(f"{flag} {path}: is an input of this command; it would be overwritten")
        for other in (*side, *written_beside(path)):
            if same_file(other, source):
                raise UsageError(
                    f"{flag} {path}: writing it would also write {other}, an input of this "
                    "command; choose another output name"
                )


def same_file(a: str, b: str) -> bool:
    """Whether two paths name one file (the same path, or links to one existing file)."""
    if os.path.abspath(a) == os.path.abspath(b):
        return True
    return os.path.exists(a) and os.path.exists(b) and os.path.samefile(a, b)


@contextlib.contextmanager
def about(path: str) -> Iterator[None]:
    """Name ``path`` in a ValueError raised inside: a refusal of that shape (size, parts)."""
    try:
        yield
    except ValueError as exc:
        raise UsageError(f"{path}: {exc}") from exc


def check_writable_folder(folder: str, path: str, *, flag: str = "-o") -> None:
    """Refuse, before any work, an output whose folder is missing or cannot be written."""
    if not os.path.isdir(folder):
        raise UsageError(f"{flag} {path}: the folder {folder} does not exist")
    # os.access sees a read-only file system even for root (EROFS); a root process ignores
    # permission bits, so only the write itself can tell then (it still fails cleanly).
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(
            f"{flag} {path}: the folder {folder} cannot be written (read-only or no "
            f"permission); choose another folder for {flag}"
        )
    # Nor where the file system refuses files of any kind (/sys, /proc): a trial's
    # "-o /sys/x.ply" failed after the work, naming a temporary file. A file made and removed.
    try:
        fd, probe = tempfile.mkstemp(prefix=".o3d-ofp-check-", dir=folder)
    except OSError as exc:
        raise UsageError(
            f"{flag} {path}: the folder {folder} cannot be written ({exc.strerror or exc}); "
            f"choose another folder for {flag}"
        ) from None
    os.close(fd)
    os.remove(probe)


def check_output_kind(path: str, faces: Any, *, flag: str = "-o") -> None:
    """Refuse, once the input is read and before any work, a point cloud to a mesh format.

    ``faces`` are those of the geometry the output copies (None for a point cloud).
    """
    from ..boundary.io import CLOUD_ONLY, MESH_ONLY

    ext = os.path.splitext(path)[1].lower()
    if faces is None and ext in MESH_ONLY:
        raise UsageError(
            f"{flag} {path}: the result is a point cloud (no faces) and cannot be written as "
            f"{ext}; use {', '.join(('.ply', *CLOUD_ONLY))}"
        )


def check_cache_dir(path: str | None) -> None:
    """Refuse, before any work, a ``--cache DIR`` that is a file or cannot be written.

    A missing folder is created later (its nearest existing parent must be writable). A
    trial's read-only cache failed after the eigensolve, naming a temporary file.
    """
    if not path:
        return
    check_folder_to_make(path, "--cache")


def check_folder_to_make(path: str, flag: str) -> None:
    """Refuse, before any work, an output folder that is a file or cannot be made or written.

    Missing folders are made later, with their parents: the nearest one that exists is
    written into and must be writable.
    """
    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"{flag} {path}: is a file, not a folder")
    existing = os.path.abspath(path)
    while not os.path.isdir(existing):  # the nearest folder that exists: it is written into
        parent = os.path.dirname(existing)
        if parent == existing or (os.path.exists(existing) and not os.path.isdir(existing)):
            raise UsageError(f"{flag} {path}: {existing} is a file, not a folder")
        existing = parent
    check_writable_folder(existing, path, flag=flag)


# --------------------------------------------------------------------------- bases


def check_job_memory(
    jobs: Sequence[tuple[str, int, int, int, int]], *, advice: str, limit: float | None = None
) -> None:
    """Refuse, before any eigensolve, bases whose estimated peak memory exceeds what is free.

    Parameters
    ----------
    jobs : sequence of (path, n_vertices, k, eig_k, order)
        The bases the command will compute (the peaks are added up: a conservative bound when
        a pair's bases are computed one after the other and both are kept).
    advice : str
        How to lower the estimate, naming the flags (e.g. ``"lower -k or --order, or use a
        simplified mesh"``), for the message.
    limit : float, optional
        Bytes allowed (default: the memory available now, from psutil).
    """
    from ..core import _memory

    if not jobs:
        return
    need = sum(
        _memory.basis_job_bytes(n, k=k, order=order, eig_k=eig_k) for _, n, k, eig_k, order in jobs
    )
    if limit is None:
        limit = _memory.available_memory()
        if limit is None:
            return
    what = " and ".join(
        f"{path} ({n} vertices, k={max(k, eig_k)}, order {order})"
        for path, n, k, eig_k, order in jobs
    )
    if need > limit:
        raise UsageError(
            f"the basis of {what} needs about {_memory.format_bytes(need)} of memory, more than "
            f"the {_memory.format_bytes(limit)} available: {advice}"
        )
    logger.debug("memory estimate for %s: %s of %s", what, _memory.format_bytes(need),
                 _memory.format_bytes(limit))  # fmt: skip


def load_basis_file(
    path: str, V: Any, F: Any, mesh_path: str, args: argparse.Namespace, flag: str
) -> Any:
    """Read the OFP basis file given as ``flag path``, checked to be ``mesh_path``'s."""
    from ..core.basis import OFPBasis
    from ..core.spectrum import shape_digest

    if not os.path.isfile(path):
        raise UsageError(f"{flag} {path}: no such basis file")
    try:
        B = OFPBasis.load(path)
    except ValueError as exc:
        raise UsageError(f"{flag} {path}: {exc}") from exc
    if B.eig.digest != shape_digest(V, F, **eig_options(args)):
        raise UsageError(
            f"{flag} {path}: this basis was computed for another mesh than {mesh_path} (or "
            "with other cleaning options); recompute it with: o3d-ofp basis " + mesh_path
        )
    return B


def _in_cache(V: Any, F: Any, k: int, args: argparse.Namespace) -> bool:
    """Tell whether ``--cache`` holds a (non-empty) entry for this basis."""
    from ..workflows.cache import basis_cache_path

    entry = basis_cache_path(
        V, F, k=k, order=args.order, cache_dir=args.cache, **tol_options(args), **eig_options(args)
    )
    return os.path.isfile(entry) and os.path.getsize(entry) > 0


def basis_for(
    V: Any,
    F: Any,
    path: str,
    args: argparse.Namespace,
    *,
    k: int | None,
    default_k: int = 29,
    k_flag: str = "-k",
    eig_k: int | None = None,
    file: str | None = None,
    file_flag: str = "--basis",
) -> tuple[Any, Any]:
    """(OFP basis on ``k`` eigenfunctions, its eigenbasis with ``eig_k`` >= k).

    From ``file`` (checked against the mesh and, when the k flag was given, ``k``), the
    ``--cache`` folder, or computed (``k`` None: ``default_k``).
    """
    from ..core.basis import ofp_basis
    from ..core.spectrum import eigenbasis
    from ..workflows.cache import cached_basis

    if file:
        B = load_basis_file(file, V, F, path, args, file_flag)
        if k is not None and B.k != k:
            raise UsageError(
                f"{file_flag} {file}: holds a basis on k={B.k} eigenfunctions, but {k_flag} {k} "
                f"was given; drop {k_flag} or recompute the basis"
            )
        check_basis_file_options(args, B, file_flag, file)
        return B, B.eig
    k = default_k if k is None else k
    if k > V.shape[0] - 2:  # before the memory estimate, which would be the message otherwise
        raise UsageError(
            f"{k_flag} {k}: must be smaller than the number of vertices of {path} minus one "
            f"({V.shape[0]} vertices: at most {V.shape[0] - 2})"
        )
    tol = tol_options(args)
    cached = getattr(args, "cache", None) and eig_k is None
    if not (cached and _in_cache(V, F, k, args)):  # a cache hit only reads its file
        check_job_memory(
            [(path, V.shape[0], k, eig_k or k, args.order)],
            advice=f"lower {k_flag} or --order, or use a simplified mesh (fewer vertices)",
        )
    if cached:
        with stage(f"basis of {path} (cache {args.cache})"):
            B = cached_basis(
                V, F, k=k, order=args.order, cache_dir=args.cache, **tol, **eig_options(args)
            )
        return B, B.eig
    eig_k = max(k, eig_k or 0)
    with stage(f"eigenbasis of {path} ({V.shape[0]} vertices, k={eig_k})"):
        eig = eigenbasis(V, F, k=eig_k, clamp_k=eig_k > k, **eig_options(args))
    with stage(f"orthogonalized products of {path} (order {args.order})"):
        return ofp_basis(eig, order=args.order, k=min(k, eig.k), **tol), eig


class _Given(argparse.Action):
    """Store the value and note that the flag was given (``args.given``: the flags' dests)."""

    def __call__(self, parser: Any, namespace: Any, values: Any, option: Any = None) -> None:
        setattr(namespace, self.dest, values)
        given = set(getattr(namespace, "given", ()) or ())
        namespace.given = given | {self.dest}


def check_basis_file_options(args: argparse.Namespace, B: Any, file_flag: str, file: str) -> None:
    """Refuse --order / --preset / --tol that disagree with a basis read from a file.

    Found by a trial: ``--basis FILE --order 3`` ran with the file's order 2, silently.
    """
    from ..core.orthogonalize import resolve_tol

    given = getattr(args, "given", set()) or set()
    if "order" in given and args.order != B.order:
        raise UsageError(
            f"{file_flag} {file}: holds a basis of order {B.order}, but --order {args.order} "
            "was given; drop --order or recompute the basis"
        )
    if given & {"tol", "preset"}:
        tol = resolve_tol(args.tol, None if args.tol is not None else args.preset)
        if not math.isclose(tol, B.tol, rel_tol=1e-9):
            flag = f"--tol {args.tol}" if args.tol is not None else f"--preset {args.preset}"
            raise UsageError(
                f"{file_flag} {file}: holds a basis orthogonalized with threshold {B.tol:g}, "
                f"but {flag} (threshold {tol:g}) was given; drop it or recompute the basis"
            )


def _file_tol(path: str) -> float | None:
    """Read the threshold of a basis file alone (None when unreadable: its full read says why)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return float(data["tol"])
    except Exception:  # any damage is reported by OFPBasis.load, later
        return None


def check_basis_files_agree(args: argparse.Namespace) -> None:
    """Refuse, before any work, two OFP bases orthogonalized with different thresholds.

    A basis file keeps its own threshold; the other side's basis is read from its file or
    made with the command's ``--preset`` / ``--tol`` (given or the command's default). A
    trial's ``detail --mode coordinates --basis-1`` with an "ours" file ran the target with
    the command's default "ours*": a transfer between bases of two thresholds, unsaid.
    """
    from ..core.orthogonalize import resolve_tol

    own = resolve_tol(args.tol, None if args.tol is not None else args.preset)
    files = [(i, f) for i, f in ((1, args.basis_1), (2, args.basis_2)) if f]
    tols = {i: _file_tol(f) for i, f in files}
    if not files or any(t is None for t in tols.values()):
        return
    t1, t2 = tols.get(1, own), tols.get(2, own)
    if math.isclose(t1, t2, rel_tol=1e-9):
        return
    preset = {1e-2: "ours", 1e-9: "ours*"}
    if len(files) == 2:
        raise UsageError(
            f"--basis-1 {args.basis_1} and --basis-2 {args.basis_2} were orthogonalized with "
            f"thresholds {t1:g} and {t2:g}: the two bases must share one; recompute one of them"
        )
    side, file = files[0]
    t = tols[side]
    name = next((n for v, n in preset.items() if math.isclose(v, t, rel_tol=1e-9)), None)
    how = f"--preset {name}" if name and args.tol is None else f"--tol {t:g}"  # --tol rules
    given = getattr(args, "given", set()) or set()
    yours = (
        f"--tol {args.tol:g}" if args.tol is not None
        else f"--preset {args.preset}" + ("" if "preset" in given else ", this command's default")
    )  # fmt: skip
    raise UsageError(
        f"--basis-{side} {file}: holds a basis orthogonalized with threshold {t:g}, but the "
        f"{'target' if side == 1 else 'source'}'s basis would be made with {own:g} ({yours}): "
        f"the two bases must share one; pass {how}, or recompute the basis file"
    )


def add_basis_options(
    p: argparse.ArgumentParser,
    *,
    k: int | None = 29,
    preset: str = "ours",
    order: int = 2,
) -> None:
    """Add the flags every basis-building command has (``-k`` only when ``k`` is given)."""
    from ._types import positive_int, unit_float

    if k is not None:
        p.add_argument("-k", "--k", type=positive_int, help=f"non-constant eigenfunctions ({k})")
    p.add_argument(
        "--order",
        type=positive_int,
        default=order,
        action=_Given,
        help=f"product order N ({order})",
    )
    p.add_argument(
        "--preset",
        choices=("ours", "ours*"),
        default=preset,
        action=_Given,
        help=f"orthogonalization threshold: ours = 1e-2, ours* = 1e-9 ({preset})",
    )
    p.add_argument(
        "--tol", type=unit_float, action=_Given, help="explicit threshold in (0, 1) (over --preset)"
    )
    p.add_argument(
        "--components",
        choices=("auto", "largest", "error"),
        default="auto",
        help="several connected components: auto keeps the largest if it holds >= 90%% of the "
        "area (else refuses), largest always keeps it, error always refuses (default: auto)",
    )
    p.add_argument(
        "--cache",
        metavar="DIR",
        help="reuse bases cached in DIR (computed and stored there the first time)",
    )
