"""Collections on a Dask cluster: one source onto many targets, and the bases of many shapes.

:func:`transfer_many` prepares the source once in the calling process (its side of the plan:
eigenbasis, OFP basis, coarse copy), broadcasts it to every worker, and runs one task per
target: read, plan, map, transfer, atomic write. A target's failure (unreadable file, refused
shape, a worker killed for memory) is that target's record; the others go on. A rerun skips
targets whose output this folder's record says was made from the same files, unchanged, with
the same options (:data:`OUTPUTS_RECORD`).

Without a ``client`` a :class:`distributed.LocalCluster` sized to the machine is started for
the call (one single-threaded worker process per core, BLAS limited to one thread per worker
through the workers' environment, its scratch space a temporary folder) and closed afterwards;
``client=`` (a :class:`distributed.Client` or a scheduler address ``"tcp://HOST:PORT"``) runs
on an existing cluster; ``workers=0`` runs everything in the calling process, one shape after
the other, without Dask. Dask is imported only when it is used.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import os
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from ..boundary.convert import geometry_to_arrays, is_open3d_geometry, like_target, vertex_colors
from ..boundary.io import CLOUD_ONLY, MESH_ONLY, read_geometry, write_geometry
from ..boundary.texture import (
    material_files,
    no_texture_message,
    surface_colors,
    texture_colors,
)
from ..core._atomic import atomic_path, output_folder
from ..core._validation import check_int
from ..core._warnings import about
from ..core.spectrum import DEFAULT_K
from ..core.wording import AdvisedError, OptionError, Said, named
from ..workflows.options import BasisOptions, DetailOptions, MatchOptions
from ..workflows.plan import plan_pair, prepare_source
from .results import TargetResult
from .tasks import BasisJob, ShapeSpec, SharedSource, TransferJob, basis_task, failed, transfer_task

__all__ = ["BLAS_ENV", "COUNTERS", "MESH_EXTENSIONS", "OUTPUTS_RECORD", "bases_many",
           "expand_paths", "local_workers", "open_client", "transfer_many"]  # fmt: skip

logger = logging.getLogger(__name__)

#: Work done in this process, for tests and benchmarks: ``"source_bases"`` counts the source
#: preparations of :func:`transfer_many` (one per call that has work to do: the source's
#: eigenbasis and OFP basis are never computed per target), ``"target_eigenbases_computed"`` /
#: ``"target_eigenbases_cached"`` the targets' eigenbases solved / loaded from the cache.
COUNTERS: Counter[str] = Counter()

#: File extensions taken from a directory given as a target or a shape.
MESH_EXTENSIONS = (".ply", *MESH_ONLY, *CLOUD_ONLY)
#: Outputs of these kinds cannot hold vertex colors: a colored target is written as ``.ply``.
_NO_COLORS = (".stl", ".xyz", ".xyzn", ".pts")
#: Outputs of a bake: OBJ + MTL + PNG. The other formats hold no UVs (as Open3D reads them):
#: their targets get vertex colors, written in their own format.
_BAKED = (".obj", ".glb", ".gltf")

#: Environment of the workers of the local cluster: one BLAS / OpenMP thread per worker, so
#: that n single-threaded workers on n cores do not oversubscribe them (set before the worker
#: process starts, which is when OpenBLAS reads it).
BLAS_ENV = {f"{name}_NUM_THREADS": "1" for name in ("OMP", "OPENBLAS", "MKL", "BLIS")}
BLAS_ENV["VECLIB_MAXIMUM_THREADS"] = "1"

#: The local cluster's scheduler: no dashboard, and its HTTP server (which it starts anyway, on
#: port 8787 by default) on a free port of 127.0.0.1, so that clusters started side by side do
#: not contend for one port.
_NO_DASHBOARD = {"dashboard": False, "dashboard_address": "127.0.0.1:0"}

#: The keywords of :func:`transfer_many`'s ``**options``, by the object each belongs to (the
#: rest are the :class:`~o3d_ofp.collections.tasks.TransferJob`'s own).
_BASIS_OPTIONS = ("k1", "k2", "order", "preset", "tol")
_DETAIL_OPTIONS = ("mode", "band", "amount")
_JOB_OPTIONS = (
    "map", "components", "strict", "shells", "same_frame", "signal", "texture_size", "atlas",
    "texture",
)

#: File of an output folder that records the files and options each output was made from (a
#: rerun with other files or options, or another kind, redoes it) and what was found then.
OUTPUTS_RECORD = ".o3d_ofp_outputs.json"
#: The fields of a target's record kept for a rerun that skips its output, and their types.
_FOUND = {"kind": str, "coverage": float, "suspect": bool, "n_vertices": int, "warnings": list,
          "notes": list}  # fmt: skip


def local_workers() -> int:
    """Return the number of cores this process may run on (the default number of workers)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def expand_paths(items: Iterable[Any]) -> list[Any]:
    """Replace every directory among ``items`` by the mesh files in it (sorted, not recursive).

    Parameters
    ----------
    items : iterable of str, os.PathLike or Open3D geometries
        Files, directories and geometries; only directories are changed.

    Returns
    -------
    list
        Files (as ``str``) and geometries, in order; a directory contributes its files with
        one of :data:`MESH_EXTENSIONS` (hidden files skipped).
    """
    out: list[Any] = []
    for item in items:
        path = os.fspath(item) if isinstance(item, (str, os.PathLike)) else None
        if path is None or not os.path.isdir(path):
            out.append(item if path is None else path)
            continue
        files = (os.path.join(path, f) for f in sorted(os.listdir(path)) if not f.startswith("."))
        out.extend(f for f in files if f.lower().endswith(MESH_EXTENSIONS) and os.path.isfile(f))
    return out


@contextlib.contextmanager
def open_client(client: Any = None, *, workers: int | None = None) -> Iterator[Any]:
    """Yield a Dask client: the one given, one connected to an address, or a local cluster's.

    Parameters
    ----------
    client : distributed.Client or str, optional
        An existing client (used as is, left open), or a scheduler address
        ``"tcp://HOST:PORT"`` (a client is opened and closed afterwards). ``None``: a
        :class:`distributed.LocalCluster` of ``workers`` single-threaded worker processes on
        127.0.0.1, BLAS limited to one thread each (:data:`BLAS_ENV`), its scratch space a
        temporary folder, closed (and the folder removed) afterwards.
    workers : int, optional
        Workers of the local cluster (default: :func:`local_workers`).

    Yields
    ------
    distributed.Client

    Raises
    ------
    ImportError
        If Dask's ``distributed`` is not installed (``pip install 'o3d_ofp[dask]'``).
    """
    try:
        import distributed
    except ImportError as exc:
        raise ImportError("collections on a cluster need Dask: pip install 'dask[distributed]' "
                          "(from a clone of o3d_ofp: pip install -e '.[dask]'); workers=0 runs in "
                          "this process without it") from exc  # fmt: skip
    if client is not None and not isinstance(client, str):
        yield client
        return
    if isinstance(client, str):
        logger.info("connecting to the Dask scheduler at %s", client)
        try:
            connected = distributed.Client(client)
        except OSError as exc:  # a timeout, a refused connection
            raise ConnectionError(f"client {client}: cannot connect to the Dask scheduler ({exc}); "
                                  "check the address (tcp://HOST:PORT) and that the scheduler is "
                                  "running") from exc  # fmt: skip
        with connected as c:
            yield c
        return
    n = local_workers() if workers is None else workers
    logger.info("starting a local Dask cluster: %d worker process%s x 1 thread", n, "es" * (n != 1))
    import dask

    # Dask's default scratch space, <tmp>/dask-scratch-space, would stay behind.
    with (
        tempfile.TemporaryDirectory(prefix="o3d_ofp-dask-", ignore_cleanup_errors=True) as scratch,
        _worker_environment() as env,
    ):
        config = {"distributed.nanny.pre-spawn-environ": env, "temporary-directory": scratch}
        with dask.config.set(config), _children_ignore_interrupts():  # the start only
            try:
                cluster = distributed.LocalCluster(  # the scheduler, nannies read the config here
                    n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                    dashboard_address=None, silence_logs=logging.ERROR,
                    scheduler_kwargs=_NO_DASHBOARD,
                )  # fmt: skip
            except RuntimeError as exc:
                raise RuntimeError(
                    f"the local Dask cluster did not start ({exc}). From a script, call this under "
                    '`if __name__ == "__main__":` (the worker processes start by importing the '
                    "script, which must not start a cluster again); or pass workers=0 to run in "
                    "this process, or client= an existing cluster") from exc  # fmt: skip
        with cluster, distributed.Client(cluster) as c:
            yield c


@contextlib.contextmanager
def _children_ignore_interrupts() -> Iterator[None]:
    """Start processes that ignore Ctrl-C: this process stops them and says so itself.

    A Ctrl-C in a terminal reaches every process of its group, and each worker would print
    its own traceback. A process started while SIGINT is ignored keeps ignoring it (Python
    installs its Ctrl-C handler only over the default one), so the workers leave it to this
    process, which closes the cluster. Only from the main thread (elsewhere signals cannot be
    set, and nothing changes).
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _worker_environment() -> Iterator[dict[str, Any]]:
    """Yield the pre-spawn environment of local workers: :data:`BLAS_ENV`, no malloc tuning.

    Dask's nannies copy ``distributed.nanny.pre-spawn-environ`` into this process's
    environment before spawning each worker (and leave it there); a variable already set in
    this process wins over that config, and a Nanny's ``env=`` comes too late for BLAS (the
    worker has imported numpy by then), so :data:`BLAS_ENV` is set here while the cluster
    lives, and everything is put back as it was afterwards.

    Dask's default ``MALLOC_TRIM_THRESHOLD_=65536`` is left out: it fixes glibc's mmap
    threshold at 128 KiB, so every temporary array of the spectral code is a fresh mmap whose
    pages fault in again. Measured on a FAUST target (6890 vertices, map estimated): 5 s of
    system time per target on top of 10 s of user time with it, 0.2-0.7 s without.
    """
    import dask

    env = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **BLAS_ENV}
    env["MALLOC_TRIM_THRESHOLD_"] = None  # None: not set (Dask's convention)
    saved = {k: os.environ.get(k) for k in [*env, "PYTHONHASHSEED"]}
    if os.environ.pop("MALLOC_TRIM_THRESHOLD_", None):
        logger.info("MALLOC_TRIM_THRESHOLD_ is set in this process's environment (by an earlier "
                    "Dask cluster?): not passed on to the workers")  # fmt: skip
    os.environ.update(BLAS_ENV)
    try:
        yield env
    finally:
        os.environ.update({k: v for k, v in saved.items() if v is not None})
        for k in (k for k, v in saved.items() if v is None):
            os.environ.pop(k, None)


def _shown(r: TargetResult) -> str:
    """Return how the log names a target: its file, and its output's name where that differs.

    An STL target's colors are written as PLY (``s087.stl`` -> ``s087.ply``): named by the
    output alone, a failure read as another input's.
    """
    given = os.path.basename(r.path) if r.path else r.name
    return given if given == r.name else f"{given} (-> {r.name})"


def _log_record(r: TargetResult) -> None:
    """Log a record as it arrives: failures and suspect maps as warnings, named."""
    who = _shown(r)
    if r.status == "failed":
        logger.warning("%s: failed: %s", who, r.error)
        return
    if r.status == "skipped":
        logger.info("%s: skipped (already done: %s)", who, r.output)
    else:
        covered = f", map coverage {r.coverage:.2f} of the source's vertices"
        covered = "" if math.isnan(r.coverage) else covered
        logger.info("%s: ok in %.1f s on %s%s", who, r.seconds, r.worker, covered)
        if r.suspect and (not r.warnings or r.worker == "local"):  # its reasons were not named
            logger.warning("%s: the map is suspect (see its record)", who)
    # A worker process's log is not shown here: its warnings are said again, named (in this
    # process, workers=0, the log said them as they happened, named: core._warnings.about).
    if r.worker != "local":
        for message in r.warnings:
            said = named(r.name, message)
            logger.warning("%s", said, extra={"said": said})


def _run(task: Callable[[Any, ShapeSpec], TargetResult], shared: Any, specs: Sequence[ShapeSpec],
         *, kind: str, client: Any, workers: int | None, progress: bool,
         on_record: Callable[[TargetResult], None]) -> None:  # fmt: skip
    """Run ``task(shared, spec)`` for every spec, with a progress bar on a terminal.

    Exceptions of a task, and a worker that died running it, become its record; ``on_record``
    is called with each record as it arrives (an interrupted run has handled every record
    that arrived before the interrupt).
    """
    from tqdm import tqdm

    if not specs:
        return
    on = progress and sys.stderr.isatty()
    with tqdm(total=len(specs), desc=kind, unit="shape", file=sys.stderr, disable=not on) as bar:

        def arrived(r: TargetResult) -> None:
            _log_record(r)
            on_record(r)
            bar.update()

        if client is None and workers == 0:
            for spec in specs:
                with about(spec.name):
                    r = task(shared, spec)
                arrived(r)
            return
        with open_client(client, workers=min(workers or local_workers(), len(specs))) as c:
            for r in _on_cluster(c, task, shared, specs, kind):
                arrived(r)


def _on_cluster(c: Any, task: Callable[[Any, ShapeSpec], TargetResult], shared: Any, specs: Any,
                kind: str) -> Iterator[TargetResult]:  # fmt: skip
    """Yield the records of the tasks run on the cluster of client ``c``, as they arrive."""
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    shared_future = c.scatter(shared, broadcast=True, hash=False)
    started = time.perf_counter()
    futures = {c.submit(task, shared_future, spec, pure=False): spec for spec in specs}
    try:
        for future in as_completed(futures):
            try:
                r = future.result()
            except Exception as exc:  # the task's own errors are records: this is Dask's
                why = f"{type(exc).__name__}: {exc}"
                if isinstance(exc, KilledWorker):
                    why = f"KilledWorker: its worker died running it (out of memory?): {exc}"
                r = failed(futures[future], why, kind=kind, seconds=time.perf_counter() - started)
            future.release()
            yield r
    finally:
        c.cancel([future for future in futures if not future.done()])
        shared_future.release()


def _names(items: Sequence[Any], kind: str) -> list[str]:
    """Return each target's output name: its file's (``target_<i>.ply`` for a geometry).

    In a format that holds what is written (a bake: OBJ + MTL + PNG; colors: not a format
    without vertex colors); names given twice (letter case aside, as some file systems read
    names) get ``-<index>`` before the suffix, said, and more (``-<index>-2`` ...) where that
    name is another target's: no two targets write one file.
    """
    parts = []
    for i, item in enumerate(items):
        name = os.path.basename(item) if isinstance(item, str) else f"target_{i}.ply"
        stem, ext = os.path.splitext(name)
        if kind == "texture" and ext.lower() in _BAKED:
            ext = ".obj"
        elif kind in ("colors", "texture") and ext.lower() in _NO_COLORS:
            ext = ".ply"
        parts.append((stem, ext))
    seen = Counter((stem + ext).casefold() for stem, ext in parts)
    taken = {key for key, count in seen.items() if count == 1}
    names = []
    for i, (stem, ext) in enumerate(parts):
        name, more = stem + ext, 1
        if seen[name.casefold()] > 1:
            name = f"{stem}-{i}{ext}"
            while name.casefold() in taken:
                more += 1
                name = f"{stem}-{i}-{more}{ext}"
            taken.add(name.casefold())
        names.append(name)
    for shared in sorted(key for key, count in seen.items() if count > 1):
        logger.info(
            "%d targets would write %s: their outputs are named %s", seen[shared], shared,
            ", ".join(n for (s, e), n in zip(parts, names, strict=True)
                      if (s + e).casefold() == shared),
        )  # fmt: skip
    return names


def _specs(items: Sequence[Any], output_dir: str | None,
           kind: str) -> tuple[list[ShapeSpec], dict[int, TargetResult]]:  # fmt: skip
    """Return the tasks' inputs, and the failed records of geometries that give no arrays.

    A file is read on the worker; a geometry is sent as arrays, its result written here.
    """
    specs, records = [], {}
    # Absolute paths: a task runs in a worker process whose working folder may be another
    # (a cluster started elsewhere, --scheduler).
    folder = None if output_dir is None else os.path.abspath(output_dir)
    for i, (item, name) in enumerate(zip(items, _names(items, kind), strict=True)):
        output = None if folder is None else os.path.join(folder, name)
        if not isinstance(item, str):
            try:
                specs.append(ShapeSpec(i, name, None, geometry_to_arrays(item), output))
            except (TypeError, ValueError) as exc:
                records[i] = failed(ShapeSpec(i, name, None), exc, kind=kind)
        elif output is not None and os.path.abspath(output) == os.path.abspath(item):
            raise ValueError(f"the output folder {output_dir} holds the target {item}: its "
                             "output would overwrite it; write to another folder")  # fmt: skip
        else:
            specs.append(ShapeSpec(i, name, os.path.abspath(item), None, output))
    return specs, records


class _OutputsRecord:
    """What each output of a folder was made from, with which options, and what was found.

    Kept in the folder's :data:`OUTPUTS_RECORD`, by output name. A rerun skips an output only
    when its record says it was made from the same files (the source, with the material and
    images its OBJ names and an explicit ``texture``, and the target: each file's absolute path,
    size and modification time) with the same options, and the output is still the file then
    written. Anything else is redone, and the log says why: an output the record does not
    list (a folder of other files included), a source or target changed, replaced or given
    in another order, other options. The record keeps the map's coverage, suspect flag,
    warnings and notes found when the output was made; under ``strict`` an output made from a
    suspect map fails its target.
    """

    def __init__(self, out_dir: str | None, job: TransferJob, source: str | None,
                 specs: Sequence[ShapeSpec]) -> None:  # fmt: skip
        self.path = None if out_dir is None else os.path.join(out_dir, OUTPUTS_RECORD)
        self.strict = job.strict
        own = {name: getattr(job, name) for name in _JOB_OPTIONS if name != "strict"}
        self.options = {"kind": job.kind, **dataclasses.asdict(job.bases or BasisOptions()),
                        **dataclasses.asdict(job.detail), **own}  # what the outputs depend on
        # The source's files, stamped once before any target runs (None: given as a geometry).
        self.source = None if source is None else [
            _stamp(f) for f in (source, *(full for _, full in material_files(source)), job.texture)
            if f
        ]  # fmt: skip
        self.targets = {spec.index: spec.path and _stamp(spec.path) for spec in specs}
        self.entries: dict[str, Any] = {}
        if self.path is not None and os.path.isfile(self.path):
            try:
                with open(self.path, encoding="utf-8") as fh:
                    self.entries = dict(json.load(fh)["outputs"])
            except (OSError, ValueError, KeyError, TypeError) as exc:
                logger.warning("%s: unreadable (%s): its outputs are redone", self.path, exc)

    def skipped(self, spec: ShapeSpec, kind: str) -> TargetResult | None:
        """Return the record of a target whose output is up to date (None: it is to be made)."""
        why = self._changed(spec)
        if why is not None:
            if why:
                logger.info("%s: %s is redone (%s)", spec.name, spec.output, why)
            return None
        found = {"kind": kind, **self._found(spec.name)}
        if self.strict and found.get("suspect"):
            return failed(spec, AdvisedError(Said(
                "suspect map (strict): {output} was made from a suspect map (see its warnings "
                "in the summary); delete it, or rerun without strict to keep it",
                {"output": spec.output}, "strict"
            )), **found)  # fmt: skip
        logger.info("%s: skipped: %s was made from these files with the same options",
                    spec.name, spec.output)  # fmt: skip
        return TargetResult(spec.index, spec.name, spec.path, "skipped", spec.output, **found)

    def _changed(self, spec: ShapeSpec) -> str | None:
        """Why the output of ``spec`` is to be made ("": nothing to say; None: it is done)."""
        if spec.output is None or self.source is None or spec.path is None:
            return ""  # nothing written, or an input given as a geometry
        if not os.path.lexists(spec.output):
            return ""
        entry = self.entries.get(spec.name)
        if not isinstance(entry, dict):
            return "not recorded as made by o3d_ofp in this folder"
        before, inputs = entry.get("options"), entry.get("inputs")
        if not isinstance(before, dict) or before.keys() != self.options.keys() or not (
                isinstance(inputs, dict)):  # fmt: skip
            return "recorded by another version of o3d_ofp"
        if inputs.get("target") != self.targets[spec.index]:
            return ("made from another target file, or the target changed since"
                    if _path_of(inputs.get("target")) == spec.path else
                    f"made from another target, {_path_of(inputs.get('target'))}")
        if inputs.get("source") != self.source:
            return "made from another source, or the source or its texture changed since"
        if before != self.options:
            return "made with other options: " + ", ".join(
                f"{k} {before[k]!r} -> {v!r}" for k, v in self.options.items() if before[k] != v)
        if entry.get("output") != _stamp(spec.output):
            return "the output was changed since it was made"
        return None

    def _found(self, name: str) -> dict[str, Any]:
        entry = self.entries.get(name)
        found = entry.get("found") if isinstance(entry, dict) else None
        if not isinstance(found, dict):
            return {}
        out = {k: found[k] for k, type_ in _FOUND.items() if isinstance(found.get(k), type_)}
        out.update({k: tuple(map(_said_of, out[k])) for k in ("warnings", "notes") if k in out})
        return out

    def made(self, result: TargetResult) -> None:
        """Record that the output of ``result`` was just made from its files with these options."""
        if self.path is not None and result.output is not None and self.source is not None:
            found = {k: v for k, v in result.row().items() if k in _FOUND}  # messages as data:
            found.update({k: [dataclasses.asdict(m) if isinstance(m, Said) else str(m)
                              for m in getattr(result, k)] for k in ("warnings", "notes")})
            inputs = {"source": self.source, "target": self.targets.get(result.index)}
            entry = {"options": self.options, "inputs": inputs, "output": _stamp(result.output),
                     "found": found}  # fmt: skip
            self.entries = {**self.entries, result.name: entry}
            self._write()

    def forget(self, specs: Iterable[ShapeSpec]) -> None:
        """Drop the records of outputs about to be made again (written at once)."""
        if self.path is not None:
            names = {spec.name for spec in specs}
            self.entries = {k: v for k, v in self.entries.items() if k not in names}
            self._write()

    def _write(self) -> None:
        assert self.path is not None
        with atomic_path(self.path, suffix=".json") as tmp, open(tmp, "w", encoding="utf-8") as fh:
            json.dump({"version": 3, "outputs": self.entries}, fh, indent=1, sort_keys=True)


def _stamp(path: str) -> list[Any] | None:
    """``[absolute path, size, modification time in ns]`` of a file; None when it is not one."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [os.path.abspath(path), st.st_size, st.st_mtime_ns] if os.path.isfile(path) else None


def _path_of(stamp: Any) -> str | None:
    """Return the path of a recorded stamp (None for a malformed one)."""
    return stamp[0] if isinstance(stamp, list) and stamp and isinstance(stamp[0], str) else None


def _said_of(item: Any) -> str | Said:
    """Return a message read back from the JSON file (a Said kept as its template and values)."""
    return Said.from_dict(item) if isinstance(item, dict) and "template" in item else str(item)


def _transfer_job(kind: str, cache_dir: str | None, options: dict[str, Any]) -> TransferJob:
    """Return the job of a :func:`transfer_many` call, each option checked by its object."""
    known = (*_BASIS_OPTIONS, *_DETAIL_OPTIONS, *_JOB_OPTIONS)
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise OptionError(unknown[0], "is not an option of transfer_many; it takes "
                          f"{', '.join(sorted(known))}")  # fmt: skip
    bases = {name: options[name] for name in _BASIS_OPTIONS if name in options}
    return TransferJob(
        kind=kind, bases=BasisOptions(**bases) if bases else None, cache_dir=cache_dir,
        detail=DetailOptions(**{n: options[n] for n in _DETAIL_OPTIONS if n in options}),
        **{name: options[name] for name in _JOB_OPTIONS if name in options},
    )  # fmt: skip


def _source(source: Any, path: str | None, job: TransferJob) -> SharedSource:
    """Read the source and run its side of the plan (any target), once for every target."""
    geometry = read_geometry(path) if path is not None else source
    if not is_open3d_geometry(geometry):
        raise OptionError("source", "must be a file or an Open3D geometry; got "
                          f"{type(source).__name__}")  # fmt: skip
    name = os.path.basename(path) if path else "source"
    V, F = geometry_to_arrays(geometry)
    signal, texture = _source_colors(geometry, path, name, job)
    if job.kind == "detail" and F is None:
        raise ValueError(f"{name}: the source of a detail transfer must be a triangle mesh")
    t0 = time.perf_counter()
    try:
        plan = plan_pair(
            V, F, None, None, task=job.task(), match=job.match, bases=job.bases,
            detail=job.detail, names=(name, "the target"),
        )  # fmt: skip
    except OptionError as exc:  # transfer_many takes the OFP bases' fields as keywords
        if exc.option != "options":
            raise
        given = [n for n in _BASIS_OPTIONS if getattr(job.bases, n) != getattr(BasisOptions(), n)]
        raise OptionError(given[0], exc.problem) from None  # the first, named as a keyword
    eig, B, cached, coarse = prepare_source(plan, V, F, match=job.match, cache_dir=job.cache_dir)
    COUNTERS["source_bases"] += 1
    logger.info(
        "source %s: %d vertices, %s%s%s%s (%.1f s); shared with every target",
        name, V.shape[0], "no eigenbasis" if eig is None else f"eigenbasis k={eig.k}",
        " (cached)" if cached else "",
        "" if B is None else f", OFP basis {B.size} functions",
        "" if coarse is None else f", coarse copy of {coarse.vertices.shape[0]} vertices",
        time.perf_counter() - t0,
    )  # fmt: skip
    return SharedSource(name, V, F, eig, B, signal, job, texture, coarse)


def _source_colors(geometry: Any, path: str | None, name: str, job: TransferJob) -> tuple[Any, Any]:
    """Return the source's colors per vertex and, for a bake, the colors of its surface.

    Its vertex colors, or its texture sampled at its vertices (``signal``); a bake reads its
    texture, else its vertex colors.
    """
    if job.kind == "detail":
        return None, None
    texture = None
    if job.kind == "texture":
        try:
            texture = surface_colors(geometry, job.texture)
        except (TypeError, ValueError, FileNotFoundError) as exc:  # its fixes kept as data
            why = (no_texture_message(path, exc) if path is not None and job.texture is None
                   else named(name, getattr(exc, "said", str(exc))))  # fmt: skip
            raise AdvisedError(Said("the source has no texture or vertex colors to bake: {why}",
                                    {"why": why}, "no_texture")) from exc  # fmt: skip
    if job.signal != "texture" and job.texture is None:
        colors = vertex_colors(geometry)
        if colors is not None:
            return colors, texture
        if job.signal == "colors":
            raise ValueError(f"{name}: the source has no vertex colors to transfer")
    try:
        colors = texture_colors(geometry, job.texture)
    except (TypeError, ValueError, FileNotFoundError) as exc:
        raise ValueError(
            f"{name}: the source has no vertex colors and no usable texture ({exc})"
        ) from exc
    if job.signal == "auto" and job.kind == "colors":
        logger.info("%s: no vertex colors; transferring its texture sampled at its vertices", name)
    return colors, texture


def transfer_many(
    source: Any,
    targets: Iterable[Any],
    *,
    kind: str = "colors",
    client: Any = None,
    output_dir: str | os.PathLike[str] | None = None,
    cache_dir: str | os.PathLike[str] | None = None,
    workers: int | None = None,
    skip_existing: bool = True,
    progress: bool = True,
    **options: Any,
) -> list[TargetResult]:
    """Transfer one source's colors, texture or geometric detail onto many targets.

    Parameters
    ----------
    source : str, os.PathLike or Open3D geometry
        The source shape (with vertex colors or a texture for ``kind="colors"``, a texture
        or, without UVs, vertex colors for ``"texture"``, a triangle mesh for ``"detail"``).
        Its eigenbasis and OFP basis are computed once, here, and shared with every task
        (``COUNTERS["source_bases"]`` counts it).
    targets : iterable of str, os.PathLike or Open3D geometries
        Target files, directories (their mesh files, sorted) and geometries.
    kind : {"colors", "texture", "detail"}, default "colors"
        Vertex colors (:func:`o3d_ofp.transfer_colors`; a target's texture image is then not
        written, with a warning); the source's texture (or vertex colors) baked into each
        target's own UV layout (:func:`o3d_ofp.transfer_texture`, written as OBJ + MTL +
        PNG; a target without UVs gets vertex colors); or detail
        (:func:`o3d_ofp.transfer_detail`).
    client : distributed.Client or str, optional
        Run on this cluster (a client, or a scheduler address ``"tcp://HOST:PORT"``). Default:
        a local cluster of ``workers`` processes, started and closed by this call.
    output_dir : str or os.PathLike, optional
        Folder of the results (created when missing): ``<output_dir>/<target file name>``
        (``target_<i>.ply`` for a geometry; ``.ply`` for a colored target whose format holds
        no colors; ``-<i>`` added to names given twice), each written atomically. ``None``:
        nothing is written and each record keeps the values (kind "texture" needs a folder).
    cache_dir : str or os.PathLike, optional
        Eigenbasis and OFP-basis cache (see :mod:`o3d_ofp.workflows.cache`): a second run over
        the same shapes solves no eigenproblem again. Damaged entries are recomputed.
    workers : int, optional
        Processes of the local cluster (default: the cores of this machine, at most one per
        target); ``0`` runs in this process without Dask. Ignored with ``client``.
    skip_existing : bool, default True
        Skip (status ``"skipped"``) a target whose output the output folder's
        ``.o3d_ofp_outputs.json`` says was made by an earlier run from the same source and
        target files (path, size and modification time; the source's material and images
        too) with the same options, and is unchanged since (never for inputs given as
        geometries; under ``strict``, an output made from a suspect map fails its target).
    progress : bool, default True
        A progress bar over the targets on stderr when it is a terminal.
    **options
        ``map`` ("estimate" (default) or "identity": targets with the source's vertices),
        ``k1`` (29), ``k2`` (39), ``order`` (2), ``preset`` ("ours" for colors, "ours*" for
        detail), ``tol``, ``mode`` ("add", "replace-detail" or "coordinates", detail, see
        :func:`o3d_ofp.transfer_detail`), ``band`` (calibrated, detail), ``amount`` (1.0, detail),
        ``components`` ("auto"), ``strict`` (False: a suspect map fails its target),
        ``shells`` (True: a doubtful map is re-estimated by registering the shapes' smooth
        shells, see :class:`o3d_ofp.MatchOptions`), ``same_frame`` (False: True when the shapes
        are given in one frame, facing the same way),
        ``signal`` ("auto": the source's vertex colors, else its texture sampled at its
        vertices; "colors"; "texture"), ``texture_size`` (1024, kind "texture"), ``atlas``
        (False; kind "texture": a mesh target without UVs gets a new UV atlas and the baked
        texture instead of vertex colors), ``texture`` (None: the source's own image; a path:
        the source's texture image, for a source read without its material).

    Returns
    -------
    list of TargetResult
        One record per target, in the order given: status, output, seconds, map coverage and
        suspect flag, error message (see :class:`TargetResult`).

    Raises
    ------
    OptionError
        For a bad option or argument, naming it (a ValueError and a TypeError), before any
        work: targets given as one path, ``workers`` < 0, a folder argument that is a file.
    ValueError, FileNotFoundError
        For a source that cannot be read or has no colors (before any target is run).
    ImportError
        When a cluster is needed and Dask is not installed.
    """
    items = _items(targets, "targets")
    _check_workers(workers, client)
    out_dir = _folder(output_dir, "output_dir")
    job = _transfer_job(kind, _folder(cache_dir, "cache_dir"), options)
    if kind == "texture" and out_dir is None:
        raise OptionError("output_dir", "is needed by kind='texture': the baked images go there")
    source_path = os.fspath(source) if isinstance(source, (str, os.PathLike)) else None
    with _output_folder(out_dir):
        specs, records = _specs(items, out_dir, kind)
        made = _OutputsRecord(out_dir, job, source_path, specs)
        for spec in specs if skip_existing else ():
            if (r := made.skipped(spec, kind)) is not None:
                records[r.index] = r
        todo = [spec for spec in specs if spec.index not in records]
        if todo:
            shared = _source(source, source_path, job)
            run = {"client": client, "workers": workers, "progress": progress}
            records.update(_transfer_targets(shared, todo, items, made, **run))
    results = [records[i] for i in range(len(items))]
    logger.info("transfer_many (%s): %s", kind, dict(Counter(r.status for r in results)))
    return results


def _transfer_targets(
    shared: SharedSource, todo: list[ShapeSpec], items: list[Any], made: _OutputsRecord, **run: Any
) -> dict[int, TargetResult]:
    """Run the targets ``todo``; each output is recorded as made as soon as it is written."""
    records: dict[int, TargetResult] = {}
    made.forget(todo)  # first: an interrupted run leaves none of them said to be made so

    def on_record(r: TargetResult) -> None:
        COUNTERS[f"target_eigenbases_{'cached' if r.cached else 'computed'}"] += r.ok
        r = _finish_in_memory(r, items[r.index], shared.job.kind)
        records[r.index] = r
        if r.status == "ok":
            made.made(r)

    try:
        _run(transfer_task, shared, todo, kind=shared.job.kind, on_record=on_record, **run)
    except KeyboardInterrupt:
        done = sum(r.status == "ok" for r in records.values())
        logger.warning("interrupted: %d of %d targets done%s%s", done, len(todo),
                       "; a rerun skips them and does the others" if made.path else "",
                       "" if run.get("client") is None else "; the tasks the cluster is running "
                       "cannot be stopped from here and may still write their outputs (a rerun "
                       "redoes them)")  # fmt: skip
        raise
    return records


def _items(values: Any, name: str) -> list[Any]:
    """Return the shapes of a collection (folders replaced by their mesh files), checked."""
    if isinstance(values, (str, bytes, os.PathLike)) or is_open3d_geometry(values):
        raise OptionError(
            name, f"must be a list of shapes (files, folders or geometries), not one "
            f"{type(values).__name__}: pass [{values!r}]",
        )  # fmt: skip
    try:
        items = expand_paths(values)
    except TypeError as exc:
        raise OptionError(name, f"must be a list of shapes; got {type(values).__name__}") from exc
    if not items:
        raise OptionError(name, "holds no shapes (an empty list, or folders without mesh files)")
    return items


def _check_workers(workers: Any, client: Any) -> None:
    """Refuse a ``workers`` that is no count of processes, or 0 (this process) with a client."""
    if workers is not None:
        check_int(workers, name="workers", minimum=0)
        if workers == 0 and client is not None:
            raise OptionError("workers", Said("=0 runs in this process: give it or {client}, "
                                              "not both"))  # fmt: skip


def _folder(value: Any, name: str, *, required: bool = False) -> str | None:
    """Return the path of a run's folder (None stays None); a file there is refused."""
    if value is None and not required:
        return None
    if not isinstance(value, (str, os.PathLike)):
        raise OptionError(name, f"must be a folder path; got {type(value).__name__}")
    path = os.fspath(value)
    if os.path.exists(path) and not os.path.isdir(path):
        raise OptionError(name, f"{path} is a file; a folder is expected (made when missing)")
    return path


@contextlib.contextmanager
def _output_folder(out_dir: str | None) -> Iterator[None]:
    """Create the output folder, refused at once when it cannot be written.

    Removed again, if empty, when the run fails (a refusal or an interrupt included).
    """
    if out_dir is None:
        yield
        return
    with output_folder(out_dir):
        if not os.access(out_dir, os.W_OK | os.X_OK):
            raise PermissionError(f"{out_dir}: the output folder cannot be written (read-only or "
                                  "no permission); choose another output folder")  # fmt: skip
        yield


def _finish_in_memory(r: TargetResult, item: Any, kind: str) -> TargetResult:
    """Write the result of a target given as a geometry like that geometry (same kind)."""
    if isinstance(item, str) or r.status != "ok" or r.output is None:
        return r
    try:
        values = {"colors" if kind == "colors" else "vertices": r.values}
        write_geometry(r.output, like_target(item, **values))
    except Exception as exc:  # a target's failure is its record, never the run's
        error = f"{type(exc).__name__}: {exc}"
        logger.warning("%s: failed to write %s: %s", r.name, r.output, error)
        return dataclasses.replace(r, status="failed", error=error, output=None, values=None)
    return dataclasses.replace(r, values=None)


def bases_many(
    paths: Iterable[Any],
    *,
    cache_dir: str | os.PathLike[str],
    client: Any = None,
    k: int = DEFAULT_K,
    order: int = 2,
    preset: str | None = "ours",
    tol: float | None = None,
    components: str = "auto",
    eigenbasis_k: int | None = MatchOptions.zoomout_to,
    workers: int | None = None,
    progress: bool = True,
) -> list[TargetResult]:
    """Compute and cache the bases of a whole collection, on the same engine as transfers.

    Each shape's OFP basis goes where :func:`o3d_ofp.cached_basis` (and the CLI's
    ``--cache``) looks for it; with ``eigenbasis_k`` its eigenbasis for map estimation is
    cached too (and the OFP basis built from it: one eigensolve per shape), so a later
    :func:`transfer_many` with the same ``cache_dir`` solves no eigenproblem.

    Parameters
    ----------
    paths : iterable of str, os.PathLike or Open3D geometries
        Shape files, directories (their mesh files, sorted) and geometries.
    cache_dir : str or os.PathLike
        The cache folder (created when missing).
    client : distributed.Client or str, optional
        As in :func:`transfer_many`.
    k, order, preset, tol, components
        The OFP basis (see :func:`o3d_ofp.cached_basis`).
    eigenbasis_k : int or None, default 99
        Also cache the eigenbasis with this many eigenfunctions (fewer on small shapes), the
        one :func:`transfer_many` estimates maps with; ``None``: only the OFP basis.
    workers : int, optional
        As in :func:`transfer_many` (``0``: in this process, without Dask).
    progress : bool, default True
        A progress bar on stderr when it is a terminal.

    Returns
    -------
    list of TargetResult
        One record per shape (``kind="basis"``, ``output`` the basis file, ``skipped`` when
        everything was already cached, ``failed`` with the message otherwise).
    """
    items = _items(paths, "paths")
    _check_workers(workers, client)
    folder = str(_folder(cache_dir, "cache_dir", required=True))
    job = BasisJob(cache_dir=folder, k=k, order=order, tol=tol, preset=preset if tol is None
                   else None, components=components, eigenbasis_k=eigenbasis_k)  # fmt: skip
    os.makedirs(folder, exist_ok=True)
    specs, records = _specs(items, None, "basis")
    _run(basis_task, job, specs, kind="basis", client=client, workers=workers, progress=progress,
         on_record=lambda r: records.update({r.index: r}))  # fmt: skip
    results = [records[i] for i in range(len(items))]
    logger.info("bases_many: %s", dict(Counter(r.status for r in results)))
    return results
