"""What the commands share: result lines, stages, checks, inputs, signals, outputs, collections.

Every check that can fail is made before the expensive work, and every message names the
file or the flag. The library's messages reach the command line in its own words: a
:class:`~o3d_ofp.core.wording.Said` is worded for flags (:func:`text_of` with ``cli=True``)
and an :class:`~o3d_ofp.core.wording.OptionError` is said of the flag that sets its option
(:data:`FLAGS`, the one table).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import glob
import importlib.util
import logging
import math
import os
import socket
import sys
import tempfile
import threading
import time
import types
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from ..boundary.convert import geometry_to_arrays, like_target, vertex_colors
from ..boundary.io import CLOUD_ONLY, MESH_ONLY, NO_COLORS, read_geometry, write_geometry
from ..boundary.texture import has_uvs, no_texture_message, texture_colors, without_texture
from ..collections import transfer_many, write_summary
from ..core import _memory
from ..core._atomic import atomic_path
from ..core.basis import OFPBasis, ofp_basis
from ..core.spectrum import eigenbasis, shape_digest
from ..core.wording import OptionError, Said, text_of
from ..render.panel import colormap
from ..workflows.cache import basis_cache_path, cached_basis
from ..workflows.options import COMPONENTS, BasisOptions, same_frame_conflict
from ._progress import ENABLED

logger = logging.getLogger(__name__)

MESH_HELP = "mesh or point cloud (any format Open3D reads: PLY, OBJ, OFF, STL, GLB, ...)"
MESH_OUT = (".ply", ".obj", ".off", ".stl", ".glb", ".gltf")
CLOUD_OUT = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")
GEOMETRY_OUT = (*MESH_OUT, *CLOUD_OUT)

#: The flags that set each option an :class:`OptionError` may name (the library's keyword or
#: options field): the error is said of those of them given (all of them when none was).
FLAGS: dict[str, tuple[str, ...]] = {
    **{name: (f"--{name}",) for name in (
        "k1", "k2", "order", "preset", "tol", "partial", "align", "landmarks", "components", "mode",
        "band", "amount", "texture", "signal", "strict", "workers", "smooth", "sharpen")},
    "shells": ("--no-shells",), "same_frame": ("--same-frame",),
    "k": ("-k",), "options": ("--k1", "--k2", "--order", "--preset", "--tol"),
    "bases": ("--basis-1", "--basis-2"), "eigenbases": ("--basis-1", "--basis-2"),
    "method": ("--map",), "map": ("--map",), "via_basis": ("--via-basis",),
    "atlas": ("--uv-atlas",), "size": ("--texture-size",), "texture_size": ("--texture-size",),
    "client": ("--scheduler",), "cache_dir": ("--cache",), "output_dir": ("-o",),
}  # fmt: skip

#: Deprecated flags and flag values, the one place they are mapped: (dest, old value, or None
#: for any) -> (what was given, the dest it sets, its value there, or None: the same).
DEPRECATED = {("k_low", None): ("--k-low", "band", None),
              ("mode", "replace"): ("--mode replace", "mode", "coordinates")}  # fmt: skip

class UsageError(Exception):
    """Bad input or arguments: one line, exit code 2 (a Said is worded for the command line)."""

    def __init__(self, message: str | Said) -> None:
        super().__init__(text_of(message, cli=True))


def refuse(*checks: tuple[Any, str | Said]) -> None:
    """Raise the :class:`UsageError` of the first ``(wrong, message)`` whose ``wrong`` holds."""
    for wrong, said in checks:
        if wrong:
            raise UsageError(said)


#: What a run's output and messages need (set by ``main``): ``quiet`` (``-q``: no result
#: lines); ``one_pair``: a run over one pair (or one shape), which prints its map's quality
#: report itself (the library's log records of it are left out) and says each warning once;
#: ``args``: the flags given; ``renamed``: the flag a deprecated one was given as
#: (``{"--band": "--k-low"}``).
OUT = types.SimpleNamespace(quiet=False, one_pair=False, args=None, renamed={})


def error_text(exc: BaseException) -> str:
    """Return the one line an error is said in on the command line (flags, not keywords)."""
    said = text_of(exc, cli=True)  # an OptionError's starts with its option's name
    if not (isinstance(exc, OptionError) and exc.option in FLAGS):
        return said
    rest = said.removeprefix(exc.option)
    if rest.startswith("="):  # a Python value (=True, ='closest') is the flag's argument
        value, _, rest = rest[1:].partition(" ")
        value = value.strip("'\"")
        rest = (f" {value} " if value not in ("", "True") else " ") + rest
    return flag_of(exc.option) + rest


def flag_of(option: str) -> str:
    """Return the flag(s) of a library option: those given of :data:`FLAGS`'s, else all."""
    flags = [OUT.renamed.get(f, f) for f in FLAGS.get(option, ())]
    given = [f for f in flags if getattr(OUT.args, dest(f), None) not in (None, False)]
    return "/".join(given or flags)


def dest(flag: str) -> str:
    """Return the argparse name of a flag (``--basis-1``: ``basis_1``)."""
    return flag.lstrip("-").replace("-", "_")


def renamed(args: argparse.Namespace) -> None:
    """Map the deprecated flags and values given to their new ones (a warning says which)."""
    for (old, value), (given, new, now) in DEPRECATED.items():
        found = getattr(args, old, None)
        if found is None or (value is not None and found != value):
            continue
        flag = f"--{new.replace('_', '-')}" + (f" {now}" if now else "")
        logger.warning("%s is deprecated; use %s", given, flag)
        other = getattr(args, new, None)
        if now is None and other is not None and other != found:
            raise UsageError(f"{given} {found} and {flag} {other} disagree: give {flag}")
        OUT.renamed.update({} if now else {flag: given})
        setattr(args, new, now or found)


def report(lines: Sequence[str | Said]) -> None:
    """Print result lines (silenced by ``-q``), a Said in the command line's words."""
    for line in lines if not OUT.quiet else ():
        sys.stdout.write(text_of(line, cli=True) + "\n")


#: Seconds between a long stage's "still running" lines (it has no progress of its own).
TICK_SECONDS = 15.0


@contextlib.contextmanager
def stage(what: str, *, ticking: bool = True) -> Iterator[None]:
    """Log a long stage at INFO: its start, that it still runs, and its duration.

    "Still running" every :data:`TICK_SECONDS` when ``ticking`` (a stage with no progress of
    its own); nothing for ``what`` empty.
    """
    if not what:
        yield
        return
    logger.info("%s ...", what)
    t0, done = time.perf_counter(), threading.Event()

    def tick() -> None:
        while not done.wait(TICK_SECONDS):
            logger.info("%s: still running (%.0f s)", what, time.perf_counter() - t0)

    if ticking:
        threading.Thread(target=tick, daemon=True).start()
    try:
        yield
    finally:
        done.set()
    logger.info("%s: done in %.2f s", what, time.perf_counter() - t0)


@contextlib.contextmanager
def about(path: str) -> Iterator[None]:
    """Name ``path`` in a ValueError raised inside: a refusal of that shape (size, parts)."""
    try:
        yield
    except OptionError:
        raise
    except ValueError as exc:
        raise UsageError(f"{path}: {text_of(exc, cli=True)}") from exc


def _number(cast: type, ok: Callable[[Any], bool], expected: str) -> Callable[[str], Any]:
    """Make an argparse ``type``: ``cast(text)``, which must satisfy ``ok`` ("expected ...")."""

    def parse(text: str) -> Any:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {value}")
        return value

    return parse


positive_int = _number(int, lambda v: v >= 1, "a positive integer")
nonnegative_int = _number(int, lambda v: v >= 0, "an integer >= 0")
unit_float = _number(float, lambda v: 0.0 < v < 1.0, "a number in (0, 1)")
positive_float = _number(float, lambda v: math.isfinite(v) and v > 0.0, "a finite number > 0")


def bounded_int(lo: int, hi: int) -> Callable[[str], int]:
    """Make an argparse type: an integer in ``[lo, hi]``."""
    return _number(int, lambda v: lo <= v <= hi, f"an integer in [{lo}, {hi}]")


def bounded_float(lo: float, hi: float) -> Callable[[str], float]:
    """Make an argparse type: a float in ``[lo, hi]``."""
    return _number(float, lambda v: lo <= v <= hi, f"a number in [{lo:g}, {hi:g}]")


def vector3(text: str) -> tuple[float, float, float]:
    """Parse three comma-separated numbers, not all zero."""
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not any(values) or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers, not all 0; got "
                                         f"{text!r}")  # fmt: skip
    return values  # type: ignore[return-value]


def read_shape(path: str) -> tuple[Any, np.ndarray, np.ndarray | None]:
    """(geometry, vertices, faces) of a mesh or cloud file; one-line errors naming the file.

    A missing file or Open3D is said by :func:`~o3d_ofp.read_geometry`.
    """
    refuse((os.path.isdir(path), f"{path}: is a directory, not a mesh file"))
    try:
        geometry = read_geometry(path)
        return (geometry, *geometry_to_arrays(geometry))
    except ValueError as exc:
        raise UsageError(f"{path}: cannot read a mesh or point cloud ({exc})") from exc


def load_npy(path: str, what: str, *, flag: str) -> np.ndarray:
    """Load a real-valued ``.npy`` array; one-line errors name the file and the flag."""
    refuse((not os.path.isfile(path), f"{flag} {path}: no such file"))
    with open(path, "rb") as fh:  # NumPy's own message speaks of pickles for other files
        refuse((fh.read(6) != b"\x93NUMPY", f"{flag} {path}: not a NumPy .npy file ({what}): it "
                "does not start with the .npy header (write it with numpy.save)"))
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise UsageError(f"{flag} {path}: not a NumPy .npy file ({what}): {exc}") from exc
    real = np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_  # (.npy: one array)
    refuse((np.iscomplexobj(arr) or not real,
            f"{flag} {path}: must hold real numbers ({what}); got dtype {arr.dtype}"))
    return arr


# --------------------------------------------------------------------------- outputs


def written_beside(path: str) -> list[str]:
    """Existing files that writing ``path`` may replace besides it.

    An OBJ's ``.mtl`` and texture images (Open3D names them ``<stem>_<i>.<ext>``), a glTF's
    ``.bin``. The writer refuses them too (``write_geometry(protect=...)``); naming them here
    lets a command refuse before any work.
    """
    stem, ext = os.path.splitext(path)
    ext = {".obj": ".mtl", ".gltf": ".bin"}.get(ext.lower())
    return [stem + ext, *sorted(glob.glob(glob.escape(stem) + "_[0-9]*.*"))] if ext else []


def check_output(path: str, allowed: Sequence[str], *, inputs: Sequence[str | None] = (),
                 flag: str = "-o", side: Sequence[str] = ()) -> None:  # fmt: skip
    """Refuse a bad output path before any work.

    Wrong extension, missing folder, a directory, or one of the inputs (which would be
    overwritten), also through a file written beside it (``side``, and those of
    :func:`written_beside`). ``inputs`` may hold flag values that are not files (``None``,
    ``"colors"``): only existing files are compared.
    """
    name = "" if os.path.isdir(path) else " name"
    refuse((os.path.isdir(path) or path.endswith(("/", os.sep)), f"{flag} {path}: is a directory"
            f"{name}; give a file name (a folder is the output of several targets)"),
           (os.path.splitext(path)[1].lower() not in allowed, f"{flag} {path}: the output must end "
            f"with one of {', '.join(dict.fromkeys(allowed))}"))  # fmt: skip
    check_writable_folder(os.path.dirname(os.path.abspath(path)), path, flag=flag)
    beside = (*side, *written_beside(path))
    files = [f for f in inputs if isinstance(f, str) and os.path.exists(f)]  # not "colors", ...
    refuse(*((os.path.isdir(o), f"{flag} {path}: writing it may also write {o} (a file Open3D "
              "writes beside it), which is a folder; choose another output name") for o in beside),
           *((same_file(path, f), f"{flag} {path}: is an input of this command; it would be "
              "overwritten") for f in files),
           *((same_file(o, f), f"{flag} {path}: writing it would also write {o}, an input of this "
              "command; choose another output name") for f in files for o in beside))  # fmt: skip


def same_file(a: str, b: str) -> bool:
    """Whether two paths name one file (the same path, or links to one existing file)."""
    if os.path.abspath(a) == os.path.abspath(b):
        return True
    return os.path.exists(a) and os.path.exists(b) and os.path.samefile(a, b)


def check_writable_folder(folder: str, path: str, *, flag: str = "-o") -> None:
    """Refuse, before any work, an output whose folder is missing or cannot be written."""
    refuse((os.path.exists(folder) and not os.path.isdir(folder),
            f"{flag} {path}: {folder} is a file, not a folder"),
           (not os.path.isdir(folder), f"{flag} {path}: the folder {folder} does not exist"))
    # os.access sees a read-only file system even for root (EROFS); a root process ignores
    # permission bits, and a file system may refuse files of any kind (/sys, /proc): only a
    # file made and removed tells, before the work rather than after it.
    why = None if os.access(folder, os.W_OK | os.X_OK) else "read-only or no permission"
    try:
        if why is None:
            fd, probe = tempfile.mkstemp(prefix=".o3d-ofp-check-", dir=folder)
            os.close(fd)
            os.remove(probe)
    except OSError as exc:
        why = exc.strerror or str(exc)
    refuse((why is not None, f"{flag} {path}: the folder {folder} cannot be written ({why}); "
            f"choose another folder for {flag}"))  # fmt: skip


def check_output_kind(path: str, faces: Any, *, flag: str = "-o") -> None:
    """Refuse, once the input is read and before any work, a point cloud to a mesh format."""
    ext = os.path.splitext(path)[1].lower()
    refuse((faces is None and ext in MESH_ONLY, f"{flag} {path}: the result is a point cloud (no "
            f"faces) and cannot be written as {ext}; use {', '.join(('.ply', *CLOUD_ONLY))}"))


def check_folder_to_make(path: str | None, flag: str) -> None:
    """Refuse, before any work, an output folder that is a file or cannot be made or written.

    Missing folders are made later, with their parents: the nearest one that exists is
    written into and must be writable (a read-only ``--cache`` is said here, not after the
    eigensolve through a temporary file). Nothing for ``path`` None.
    """
    if not path:
        return
    existing = os.path.abspath(path)
    while not os.path.isdir(existing):  # the nearest folder that exists: it is written into
        parent = os.path.dirname(existing)
        if parent == existing or os.path.exists(existing):
            raise UsageError(f"{flag} {path}: {existing} is a file, not a folder")
        existing = parent
    check_writable_folder(existing, path, flag=flag)


# --------------------------------------------------------------------------- bases


def add_basis_options(p: argparse.ArgumentParser, *, k: bool = True, preset: str = "ours") -> None:
    """Add the flags of the commands that build bases (``-k``: one shape's size).

    The defaults are :class:`~o3d_ofp.BasisOptions`'; ``preset``: the command's, for the help.
    """
    default = BasisOptions()
    if k:
        p.add_argument("-k", "--k", type=positive_int,
                       help=f"non-constant eigenfunctions ({default.k1})")  # fmt: skip
    p.add_argument("--order", type=positive_int, help=f"product order N ({default.order})")
    p.add_argument("--preset", choices=("ours", "ours*"),
                   help=f"orthogonalization threshold: ours = 1e-2, ours* = 1e-9 ({preset})")
    p.add_argument("--tol", type=unit_float, help="explicit threshold in (0, 1) (over --preset)")
    add_components_option(p)
    p.add_argument("--cache", metavar="DIR",
                   help="reuse bases cached in DIR (computed and stored there the first time)")


def add_components_option(p: argparse.ArgumentParser) -> None:
    """Add ``--components``, the policy for a shape of several connected components."""
    p.add_argument("--components", choices=COMPONENTS, default="auto",
                   help="several connected components: auto keeps the largest if it holds >= 90%% "
                   "of the area (else refuses), largest always keeps it, error always refuses "
                   "(default: auto)")  # fmt: skip


def basis_flags(args: argparse.Namespace, **sizes: int | None) -> dict[str, Any]:
    """Return the basis flags given, as keywords (``--tol`` is over ``--preset``).

    ``sizes``: the sizes of a one-shape command (its ``-k``), over ``--k1``/``--k2``.
    """
    given = {"k1": getattr(args, "k1", None), "k2": getattr(args, "k2", None), **sizes,
             "order": args.order, "preset": None if args.tol is not None else args.preset,
             "tol": args.tol}  # fmt: skip
    return {name: value for name, value in given.items() if value is not None}


def basis_options(args: argparse.Namespace, **sizes: int | None) -> BasisOptions | None:
    """Return the :class:`~o3d_ofp.BasisOptions` the flags give (None when none was given)."""
    given = basis_flags(args, **sizes)
    return BasisOptions(**given) if given else None


def check_memory(path: str, n: int, *, k: int, order: int, advice: str) -> None:
    """Refuse, before its eigensolve, a one-shape job that cannot fit in the free memory.

    A pair's job is checked by :func:`o3d_ofp.workflows.plan.prepare`.
    """
    need, limit = _memory.basis_job_bytes(n, k=k, order=order), _memory.available_memory()
    if limit is not None and need > limit:
        need, limit = _memory.format_bytes(need), _memory.format_bytes(limit)
        raise UsageError(f"the basis of {path} ({n} vertices, k={k}, order {order}) needs about "
                         f"{need} of memory, more than the {limit} available: {advice}")


def load_basis_file(path: str, V: Any, F: Any, mesh: str, args: Any, flag: str) -> OFPBasis:
    """Read the OFP basis file given as ``flag path``, checked to be ``mesh``'s."""
    refuse((not os.path.isfile(path), f"{flag} {path}: no such basis file"))
    try:
        B = OFPBasis.load(path)
    except ValueError as exc:
        raise UsageError(f"{flag} {path}: {exc}") from exc
    refuse((B.eig.digest != shape_digest(V, F, components=args.components), f"{flag} {path}: "
            f"this basis was computed for another mesh than {mesh} (or with other cleaning "
            f"options); recompute it with: o3d-ofp basis {mesh}"))  # fmt: skip
    return B


def check_basis_flags(B: OFPBasis, given: str, args: Any, k_flag: str, k: int | None,
                      tol: float) -> None:  # fmt: skip
    """Refuse flags that contradict a basis read from a file (``given``: "--basis FILE").

    ``k_flag``, ``k``: the flag of its eigenfunctions and its value (None: not given);
    ``--order`` and ``--preset`` / ``--tol`` (threshold ``tol``) are read from ``args``.
    """
    for flag, value, what, held in ((k_flag, k, f"on k={B.k} eigenfunctions", B.k),
                                    ("--order", args.order, f"of order {B.order}", B.order)):
        refuse((value is not None and value != held, f"{given}: holds a basis {what}, but "
                f"{flag} {value} was given; drop {flag} or recompute the basis"))  # fmt: skip
    threshold = f"--tol {args.tol}" if args.tol is not None else f"--preset {args.preset}"
    refuse(((args.tol or args.preset) and not np.isclose(tol, B.tol, rtol=1e-9),
            f"{given}: holds a basis orthogonalized with threshold {B.tol:g}, but "
            f"{threshold} (threshold {tol:g}) was given; drop it or recompute the basis"))


def shape_basis(V: Any, F: Any, path: str, args: argparse.Namespace) -> OFPBasis:
    """Return the OFP basis of one shape: from ``--basis``, the ``--cache`` folder, or computed.

    A basis file is checked against the flags given; sizes and threshold: :func:`basis_options`.
    """
    options = basis_options(args, k1=args.k) or BasisOptions()
    k, order, tol = options.k1, options.order, options.threshold("ours")
    if getattr(args, "basis", None):
        B = load_basis_file(args.basis, V, F, path, args, "--basis")
        check_basis_flags(B, f"--basis {args.basis}", args, "-k", args.k, tol)
        return B
    refuse((k > V.shape[0] - 2, f"-k {k}: must be smaller than the number of vertices of {path} "
            f"minus one ({V.shape[0]} vertices: at most {V.shape[0] - 2})"))  # (before the memory
    # estimate, whose message it would be otherwise)
    cached = {"k": k, "order": order, "tol": tol, "cache_dir": args.cache,
              "components": args.components}  # fmt: skip
    entry = args.cache and basis_cache_path(V, F, **cached)
    if not (entry and os.path.isfile(entry) and os.path.getsize(entry) > 0):  # a hit only reads
        check_memory(path, V.shape[0], k=k, order=order,
                     advice="lower -k or --order, or use a simplified mesh (fewer vertices)")
    with about(path):
        if args.cache:
            with stage(f"basis of {path} (cache {args.cache})"):
                return cached_basis(V, F, **cached)
        with stage(f"eigenbasis of {path} ({V.shape[0]} vertices, k={k})"):
            eig = eigenbasis(V, F, k=k, components=args.components)
        with stage(f"orthogonalized products of {path} (order {order})"):
            return ofp_basis(eig, order=order, k=min(k, eig.k), tol=tol)


# --------------------------------------------------------------------------- signals


def read_signal(geometry: Any, V: np.ndarray, path: str, spec: str, texture: str | None,
                output: str | None = None) -> tuple[np.ndarray, str]:  # fmt: skip
    """(values (n,) or (n, d), kind) of ``--signal`` on the geometry read from ``path``.

    With ``output`` (the ``-o`` path), colors bound for a format that holds none (STL, XYZ)
    are refused here, before any work: they would be dropped without a word.
    """
    other = texture is not None and spec != "texture"
    refuse((other and not has_uvs(geometry), f"--texture {texture}: {path} has no texture "
            "coordinates (UVs) to map an image onto; drop --texture"),
           (other, "--texture applies to --signal texture"),
           (texture is not None and not os.path.isfile(texture),
            f"--texture {texture}: no such image file"))  # fmt: skip
    if spec == "xyz":
        return V, "xyz"
    if spec.endswith(".npy"):
        f = load_npy(spec, "per-vertex signal", flag="--signal")
        refuse((f.ndim not in (1, 2) or f.shape[0] != V.shape[0], f"--signal {spec}: has shape "
                f"{f.shape} but {path} has {V.shape[0]} vertices (expected (n,) or (n, d))"),
               (not np.all(np.isfinite(f)), f"--signal {spec}: must hold finite numbers"))
        return f.astype(np.float64), "array"
    colors = vertex_colors(geometry) if spec == "colors" else None
    hint = ("it has texture coordinates: use --signal texture" if has_uvs(geometry) else
            "transfer its coordinates (--signal xyz) or a per-vertex signal (--signal FILE.npy)")
    refuse((spec not in ("colors", "texture"),
            f"--signal must be colors, texture, xyz or a FILE.npy; got {spec!r}"),
           (spec == "colors" and colors is None, f"{path}: has no vertex colors ({hint})"))
    try:
        colors = texture_colors(geometry, texture) if colors is None else colors
    except (ValueError, TypeError, FileNotFoundError) as exc:
        raise texture_error(path, texture, exc) from exc
    check_colors_output(output)
    return colors, "colors"


def check_colors_output(output: str | None) -> None:
    """Refuse colors bound for an ``-o`` format that holds none (STL, XYZ), before any work."""
    ext = os.path.splitext(output or "")[1].lower()
    refuse((ext in NO_COLORS, f"-o {output}: {ext} holds no vertex colors, so the colors would be "
            "lost; write .ply, .obj, .off, .glb, .gltf (meshes) or .xyzrgb, .pcd, .pts (points)"))


def texture_error(path: str, texture: str | None, exc: Exception) -> UsageError:
    """Return the error of a texture that cannot be read (``--texture FILE``, or the source's).

    The source's own names the files its material lacks.
    """
    if texture is not None:  # the given image, not the source, is at fault
        return UsageError(f"--texture {texture}: "
                          + text_of(exc, cli=True).removeprefix(f"{texture}: "))  # fmt: skip
    return UsageError(no_texture_message(path, exc))


def side_outputs(path: str, kind: str) -> list[str]:
    """Files besides ``path`` that :func:`write_result` writes for a signal of ``kind``."""
    if kind == "array" and not path.lower().endswith(".npy"):
        return [os.path.splitext(path)[0] + ".npy"]
    return []


def signal_sides(args: Any) -> list[str]:
    """Side files of ``-o`` known from the flags: the ``.npy`` of a ``--signal FILE.npy``."""
    npy = str(getattr(args, "signal", None)).lower().endswith(".npy")
    return side_outputs(args.output, "array" if npy else "")


def write_result(path: str, like: Any, values: np.ndarray, kind: str,
                 protect: Sequence[str | None] = ()) -> list[str]:  # fmt: skip
    """Write ``values`` on a copy of the geometry ``like``: colored, moved, or a ``.npy``.

    A colored copy has no texture image (its UVs are kept): the colors replace it. Returns
    the files written. A general signal goes to a ``.npy`` beside the geometry, which
    shows its first channel through a colormap. Nothing is written when a file would replace
    one of ``protect`` (the command's inputs).
    """
    sides = side_outputs(path, kind)
    for side in sides:
        check_output(side, (".npy",), inputs=protect, flag="-o (its .npy beside it)")
    geometry = not path.lower().endswith(".npy")  # (else the values alone)
    if geometry:
        rgb = kind == "colors" or (values.ndim == 2 and values.shape[1] == 3)
        colors = np.clip(values, 0, 1) if rgb else colormap(values.reshape(len(values), -1)[:, 0])
        out = like_target(like, vertices=values) if kind == "xyz" else without_texture(
            like_target(like, colors=colors))  # fmt: skip
    for npy in sides if geometry else [path]:
        with atomic_path(npy, suffix=".npy") as tmp:
            np.save(tmp, values)
    if geometry:
        write_geometry(path, out, protect=protect)
    return [path, *sides]


# --------------------------------------------------------------------------- several shapes
# One source onto a list or folder of targets (transfer/detail TARGET... -o DIR), and basis of
# a collection, run on the collection engine (o3d_ofp.collections, on Dask): the source's bases
# are computed once, each target is a task, a failing target is reported and never stops the
# others, every result is written atomically to DIR/<target file name>, and a rerun skips
# targets whose output was made from the same files with the same options. The summary is
# printed (one line per target) and written as DIR/summary.csv and DIR/summary.json; the exit
# code is 1 when any target failed.


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
    "summary.csv and summary.json"), force: bool = True) -> None:  # fmt: skip
    """Add the flags of runs over several shapes (``description``: what such a run writes).

    ``force``: the flag that redoes outputs a rerun would skip (not for ``basis``, whose cached
    entries are checked instead).
    """
    g = p.add_argument_group("several shapes", description)
    g.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask cluster "
                   "(default: a local cluster, one worker process per core)")
    g.add_argument("--workers", type=nonnegative_int, help="worker processes of the local cluster "
                   "(default: the cores; 0: in this process)")
    if force:
        g.add_argument("--force", action="store_true", help="redo every target (default: skip "
                       "those whose output an earlier run made from the same files, unchanged, "
                       "with the same options)")  # fmt: skip


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
        if getattr(args, flag[2:], None) not in (None, False):
            raise UsageError(f"{flag} applies to several targets (TARGET... or a folder)")
    OUT.one_pair = True  # its quality report is printed, not logged; a warning said once
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


def report_records(records: Sequence[Any], *after: str) -> int:
    """Print one line per shape, a count and the lines ``after``; return 1 when any failed.

    With ``-q`` nothing is printed here: the failures and the suspect maps were logged as
    warnings, which ``-q`` keeps (each named: the exit code 1 alone would not say which shapes
    failed, nor why).
    """
    counts = {s: sum(r.status == s for r in records) for s in ("ok", "failed", "skipped")}
    report([*map(_line, records), ", ".join(f"{n} {s}" for s, n in counts.items()), *after])
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
    one pair (:data:`PAIR_ONLY`), a bad ``-o DIR``, a cluster without Dask, a bad scheduler and
    a missing source or target are refused before any work.
    """
    path, ext = args.output, os.path.splitext(args.output)[1].lower()
    refuse(*((getattr(args, name, None) not in (None, False), f"{flag} does not apply to several "
              "targets") for name, flag in PAIR_ONLY.items()),
           (os.path.exists(path) and not os.path.isdir(path), f"-o {path}: is a file; with several "
            "targets -o names a folder"),
           (not os.path.exists(path) and ext in (*GEOMETRY_OUT, ".npy"), f"-o {path}: with several "
            f"targets -o names a folder (the results keep the targets' names); {ext} looks like "
            "one output file"))  # fmt: skip
    check_folder_to_make(path, "-o")  # written into, or made in its nearest folder
    check_folder_to_make(args.cache, "--cache")
    if (args.scheduler or args.workers != 0) and importlib.util.find_spec("distributed") is None:
        raise UsageError("several targets run on a Dask cluster, and Dask is not installed: pip "
                         "install 'dask[distributed]' (from a clone of o3d_ofp: pip install -e "
                         "'.[dask]'), or give --workers 0 to run them one after the other here")
    if args.scheduler:
        _check_scheduler(args.scheduler)
    frame = same_frame_conflict(partial=False, landmarks=False, shells=not args.no_shells)
    refuse(  # a typo in a target's name is said before any work
        (args.map not in ("estimate", "identity"), f"--map {args.map}: with several targets the "
         "map is 'estimate' or 'identity'"),
        *((on and args.map != "estimate", f"{flag} applies to --map estimate, not --map "
           f"{args.map}") for flag, on in (("--no-shells", args.no_shells),
                                              ("--same-frame", args.same_frame))),
        (args.same_frame and frame is not None and args.map == "estimate",
         f"--same-frame {frame and text_of(frame, cli=True)}"),
        (not os.path.isfile(args.source), f"{args.source}: no such source file"),
        *((not os.path.exists(t), f"{t}: no such target file or folder") for t in args.target),
    )  # fmt: skip
    given = {**basis_flags(args), **options}
    records = transfer_many(args.source, args.target, kind=kind, client=args.scheduler,
                            output_dir=args.output, cache_dir=args.cache, workers=args.workers,
                            skip_existing=not args.force, progress=ENABLED.on, map=args.map,
                            components=args.components, strict=args.strict,
                            shells=not args.no_shells, same_frame=args.same_frame,
                            **{name: value for name, value in given.items() if value is not None})
    words = functools.partial(text_of, cli=True)  # what was said of each target, for flags
    records = [dataclasses.replace(r, error=words(r.error), warnings=tuple(map(words, r.warnings)),
                                   notes=tuple(map(words, r.notes))) for r in records]
    csv_path, json_path = write_summary(records, args.output)
    return report_records(records, f"summary: {csv_path}, {json_path}")
