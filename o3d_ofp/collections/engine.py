"""Collections on a Dask cluster: one source onto many targets, and the bases of many shapes.

:func:`transfer_many` prepares the source once in the calling process (its eigenbasis for map
estimation and its OFP basis), broadcasts it to every worker, and runs one task per target:
read, eigenbasis (from the cache when there is one), map, transfer, atomic write. A target's
failure (unreadable file, refused shape, a worker killed for memory) is that target's record;
the others go on. A rerun skips targets whose output is newer than both inputs and was made
with the same options (:data:`OUTPUTS_RECORD`).

Without a ``client`` a :class:`distributed.LocalCluster` sized to the machine is started for
the call (one single-threaded worker process per core, BLAS limited to one thread per worker
through the workers' environment) and closed afterwards; ``client=`` (a
:class:`distributed.Client` or a scheduler address ``"tcp://HOST:PORT"``) runs on an existing
cluster; ``workers=0`` runs everything in the calling process, one shape after the other,
without Dask. Dask is imported only when it is used.
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
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from ..boundary.convert import (
    geometry_to_arrays,
    is_open3d_geometry,
    like_target,
    vertex_colors,
)
from ..boundary.io import read_geometry, write_geometry
from ..boundary.texture import no_texture_message, surface_colors, texture_colors
from ..core._atomic import atomic_path, output_folder
from ..core._validation import check_int
from ..core.orthogonalize import resolve_tol
from ..core.texture import MAX_TEXTURE_SIZE
from ..core.wording import OptionError
from ..workflows.options import (
    COMPONENTS,
    ESTIMATION_K,
    BasisOptions,
    DetailOptions,
    check_bool,
    check_choice,
)
from ..workflows.plan import plan_pair, prepare_source
from .results import TargetResult
from .tasks import (
    BasisJob,
    ShapeSpec,
    SharedSource,
    TransferJob,
    basis_task,
    failed,
    transfer_task,
)

__all__ = [
    "BLAS_ENV",
    "COUNTERS",
    "MESH_EXTENSIONS",
    "bases_many",
    "expand_paths",
    "local_workers",
    "open_client",
    "transfer_many",
]

logger = logging.getLogger(__name__)

#: Work done in this process, for tests and benchmarks: ``"source_bases"`` counts the source
#: preparations of :func:`transfer_many` (one per call that has work to do: the source's
#: eigenbasis and OFP basis are never computed per target), ``"target_eigenbases_computed"`` /
#: ``"target_eigenbases_cached"`` the targets' eigenbases solved / loaded from the cache.
COUNTERS: Counter[str] = Counter()

#: File extensions taken from a directory given as a target or a shape.
MESH_EXTENSIONS = (
    ".ply", ".obj", ".off", ".stl", ".glb", ".gltf", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts",
)  # fmt: skip
#: Outputs of these kinds cannot hold vertex colors: a colored target is written as ``.ply``.
_NO_COLORS = (".stl", ".xyz", ".xyzn", ".pts")

#: Environment of the workers of the local cluster: one BLAS / OpenMP thread per worker, so
#: that n single-threaded workers on n cores do not oversubscribe them (set before the worker
#: process starts, which is when OpenBLAS reads it).
BLAS_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "BLIS_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
}

#: The options of :func:`transfer_many` (its ``**options``) and the object each belongs to.
_BASIS_OPTIONS = ("k1", "k2", "order", "preset", "tol")
_DETAIL_OPTIONS = ("mode", "band", "amount")
_JOB_OPTIONS = ("map", "components", "strict", "signal", "texture_size", "atlas", "texture")
#: What each kind of transfer is.
KINDS = ("colors", "texture", "detail")


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
        if isinstance(item, (str, os.PathLike)):
            path = os.fspath(item)
            if os.path.isdir(path):
                out.extend(
                    os.path.join(path, f)
                    for f in sorted(os.listdir(path))
                    if not f.startswith(".")
                    and f.lower().endswith(MESH_EXTENSIONS)
                    and os.path.isfile(os.path.join(path, f))
                )
            else:
                out.append(path)
        else:
            out.append(item)
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
        127.0.0.1, BLAS limited to one thread each (:data:`BLAS_ENV`), closed afterwards.
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
        raise ImportError(
            "collections on a cluster need Dask: pip install 'dask[distributed]' (from a "
            "clone of o3d_ofp: pip install -e '.[dask]'); workers=0 runs in this process "
            "without it"
        ) from exc
    if client is not None and not isinstance(client, str):
        yield client
        return
    if isinstance(client, str):
        logger.info("connecting to the Dask scheduler at %s", client)
        try:
            connected = distributed.Client(client)
        except OSError as exc:  # a timeout, a refused connection
            raise ConnectionError(
                f"client {client}: cannot connect to the Dask scheduler ({exc}); check the "
                "address (tcp://HOST:PORT) and that the scheduler is running"
            ) from exc
        with connected as c:
            yield c
        return
    n = local_workers() if workers is None else workers
    logger.info(
        "starting a local Dask cluster: %d worker process%s x 1 thread", n, "es" * (n != 1)
    )
    import dask

    # The workers' scratch space is a folder of this run's, removed with the cluster (Dask's
    # default, <tmp>/dask-scratch-space, stays behind).
    with _worker_environment() as pre_spawn, tempfile.TemporaryDirectory(
        prefix="o3d_ofp-dask-"
    ) as scratch:  # fmt: skip
        config = {"distributed.nanny.pre-spawn-environ": pre_spawn}
        with dask.config.set(config), _children_ignore_interrupts():  # the start only
            try:
                cluster = distributed.LocalCluster(  # the nannies read the config here
                    n_workers=n,
                    threads_per_worker=1,
                    processes=True,
                    host="127.0.0.1",
                    dashboard_address=None,
                    silence_logs=logging.ERROR,
                    local_directory=scratch,
                )
            except RuntimeError as exc:
                raise RuntimeError(
                    f"the local Dask cluster did not start ({exc}). From a script, call this "
                    "under `if __name__ == \"__main__\":` (the worker processes start by "
                    "importing the script, which must not start a cluster again); or pass "
                    "workers=0 to run in this process, or client= an existing cluster"
                ) from exc
        with cluster, distributed.Client(cluster) as c:
            yield c


@contextlib.contextmanager
def _children_ignore_interrupts() -> Iterator[None]:
    """Start processes that ignore Ctrl-C: this process stops them and says so itself.

    A Ctrl-C in a terminal reaches every process of its group: each worker of a local cluster
    printed its own KeyboardInterrupt traceback. A process started while SIGINT is ignored
    keeps ignoring it (Python installs its Ctrl-C handler only over the default one), so the
    workers leave it to this process, which closes the cluster. Only from the main thread
    (elsewhere signals cannot be set, and nothing changes).
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

    env: dict[str, Any] = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    env.update(BLAS_ENV)
    env["MALLOC_TRIM_THRESHOLD_"] = None  # None: not set (Dask's convention)
    keys = [*env, "PYTHONHASHSEED"]
    saved = {k: os.environ.get(k) for k in keys}
    if os.environ.get("MALLOC_TRIM_THRESHOLD_"):
        logger.info(
            "MALLOC_TRIM_THRESHOLD_ is set in this process's environment (by an earlier Dask "
            "cluster?): not passed on to the workers"
        )
        os.environ.pop("MALLOC_TRIM_THRESHOLD_")
    # Dask takes a variable already in this process's environment over its config, and a
    # Nanny's env= is applied after the worker has imported numpy: set them here.
    os.environ.update(BLAS_ENV)
    try:
        yield env
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _progress_bar(total: int, desc: str, enabled: bool) -> Any:
    from tqdm import tqdm

    on = enabled and sys.stderr.isatty()
    return tqdm(total=total, desc=desc, unit="shape", file=sys.stderr, disable=not on)


def _log_record(r: TargetResult) -> None:
    if r.status == "failed":
        logger.warning("%s: failed: %s", r.name, r.error)
    elif r.status == "skipped":
        logger.info("%s: skipped (already done: %s)", r.name, r.output)
    else:
        extra = ""
        if not math.isnan(r.coverage):
            extra = f", map coverage {r.coverage:.2f} of the source's vertices"
        logger.info("%s: ok in %.1f s on %s%s", r.name, r.seconds, r.worker, extra)
        # Named here when its reasons were not (a worker's are said again below, named; this
        # process's log said them without the target's name).
        if r.suspect and (not r.warnings or r.worker == "local"):
            logger.warning("%s: the map is suspect (see its record)", r.name)
    # A worker process's log is not shown here: its warnings are said again, named. In this
    # process (workers=0) the log already said them.
    if r.status != "failed" and r.worker != "local":
        for message in r.warnings:
            logger.warning("%s: %s", r.name, message)


@contextlib.contextmanager
def _warnings_named(name: str) -> Iterator[None]:
    """Start the library's warnings logged meanwhile with ``name`` (a target run in-process).

    A worker's warnings are said again with the target's name (:func:`_log_record`); in this
    process (``workers=0``) they are said once, as they happen: a trial's "the target already
    has detail" lines did not say which target.
    """
    previous = logging.getLogRecordFactory()

    def factory(*args: Any, **kwargs: Any) -> logging.LogRecord:
        record = previous(*args, **kwargs)
        if record.levelno >= logging.WARNING and record.name.startswith("o3d_ofp."):
            record.msg, record.args = f"{name}: {record.getMessage()}", ()
        return record

    logging.setLogRecordFactory(factory)
    try:
        yield
    finally:
        logging.setLogRecordFactory(previous)


def _run(
    task: Callable[[Any, ShapeSpec], TargetResult],
    shared: Any,
    specs: Sequence[ShapeSpec],
    *,
    kind: str,
    client: Any,
    workers: int | None,
    progress: bool,
    on_record: Callable[[TargetResult], None] | None = None,
) -> list[TargetResult]:
    """Run ``task(shared, spec)`` for every spec; exceptions of a task become its record.

    ``on_record`` is called with each record as it arrives (an interrupted run has handled
    every record that arrived before the interrupt).
    """
    if not specs:
        return []
    records: list[TargetResult] = []
    bar = _progress_bar(len(specs), kind, progress)
    with bar:
        if client is None and workers == 0:
            for spec in specs:
                with _warnings_named(spec.name):
                    r = task(shared, spec)
                _log_record(r)
                if on_record is not None:
                    on_record(r)
                records.append(r)
                bar.update()
            return records
        n = None if workers is None else min(workers, len(specs))
        if client is None and n is None:
            n = min(local_workers(), len(specs))
        with open_client(client, workers=n) as c:
            records = _run_on(c, task, shared, specs, kind=kind, bar=bar, on_record=on_record)
    return records


def _run_on(
    c: Any,
    task: Callable[[Any, ShapeSpec], TargetResult],
    shared: Any,
    specs: Sequence[ShapeSpec],
    *,
    kind: str,
    bar: Any,
    on_record: Callable[[TargetResult], None] | None = None,
) -> list[TargetResult]:
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    threads = c.nthreads()
    if threads and max(threads.values()) > 1:
        logger.info(
            "some Dask workers run %d threads: correct (the library is thread-safe), but their "
            "shapes share the process's cores and BLAS thread limits; one thread per worker "
            "process is usually faster",
            max(threads.values()),
        )
    token = uuid.uuid4().hex[:8]
    shared_future = c.scatter(shared, broadcast=True, hash=False)
    started = time.perf_counter()
    futures = {
        c.submit(
            task, shared_future, spec, key=f"o3d-ofp-{kind}-{spec.index}-{token}", pure=False
        ): spec
        for spec in specs
    }
    records = []
    try:
        for future in as_completed(futures):
            spec = futures[future]
            try:
                r = future.result()
            except KilledWorker as exc:
                r = failed(
                    spec,
                    f"KilledWorker: the worker running this shape died (out of memory?): {exc}",
                    kind=kind,
                    seconds=time.perf_counter() - started,
                )
            except Exception as exc:  # the task's own errors are records; this is Dask's
                r = failed(
                    spec, f"{type(exc).__name__}: {exc}", kind=kind,
                    seconds=time.perf_counter() - started,
                )  # fmt: skip
            future.release()
            _log_record(r)
            if on_record is not None:
                on_record(r)
            records.append(r)
            bar.update()
    finally:
        for future in futures:
            if not future.done():
                future.cancel()
        shared_future.release()
    return records


def _outputs(
    items: Sequence[Any], output_dir: str | None, kind: str
) -> tuple[list[str], list[str | None]]:
    """(name, output path) of every target; duplicate names get ``-<index>`` before the suffix."""
    names = []
    for i, item in enumerate(items):
        if isinstance(item, str):
            name = os.path.basename(item)
            if kind == "texture" and name.lower().endswith((".obj", ".glb", ".gltf")):
                # OBJ + MTL + PNG (vertex colors for a target without UVs). The other formats
                # hold no UVs (as Open3D reads them): their targets get vertex colors, written
                # as for kind "colors" (a trial's PLY target came out as an OBJ with colors)
                name = os.path.splitext(name)[0] + ".obj"
            elif kind in ("colors", "texture") and name.lower().endswith(_NO_COLORS):
                name = os.path.splitext(name)[0] + ".ply"
        else:
            name = f"target_{i}.ply"
        names.append(name)
    seen = Counter(names)
    renamed = [
        f"{os.path.splitext(n)[0]}-{i}{os.path.splitext(n)[1]}" if seen[n] > 1 else n
        for i, n in enumerate(names)
    ]
    for shared in sorted(n for n, count in seen.items() if count > 1):
        logger.info(
            "%d targets would write %s: their outputs are named %s",
            seen[shared],
            shared,
            ", ".join(new for old, new in zip(names, renamed, strict=True) if old == shared),
        )
    names = renamed
    if output_dir is None:
        return names, [None] * len(names)
    outs: list[str | None] = []
    for item, name in zip(items, names, strict=True):
        out = os.path.join(output_dir, name)
        if isinstance(item, str) and os.path.abspath(out) == os.path.abspath(item):
            raise ValueError(
                f"the output folder {output_dir} holds the target {item}: its output would "
                "overwrite it; write to another folder"
            )
        outs.append(out)
    return names, outs


#: File of an output folder that records the options each output was made with, so that a
#: rerun with other options (or another command) redoes it instead of skipping it.
OUTPUTS_RECORD = ".o3d_ofp_outputs.json"


class _OutputsRecord:
    """The options each output of a folder was made with (:data:`OUTPUTS_RECORD`).

    A rerun skips an output newer than its inputs only when it was made with the same
    options: found by a trial, a rerun with ``--k1 20`` (or ``detail`` over a folder of color
    transfers) reported every target "up to date" and kept the old results. Outputs of a
    folder without the record (made before it existed) are judged by their times alone.
    """

    def __init__(self, out_dir: str | None, job: TransferJob) -> None:
        self.path = None if out_dir is None else os.path.join(out_dir, OUTPUTS_RECORD)
        options = dataclasses.asdict(job)
        for key in ("cache_dir", "strict"):  # where the bases come from; no effect on outputs
            options.pop(key)
        self.options = options
        self.outputs: dict[str, dict[str, Any]] | None = None
        # What was found when each output was made (map coverage, suspect flag, warnings,
        # notes): a rerun that skips it keeps them in its record and summary. Found by a
        # trial: a rerun's summary had the suspect flags of the outputs it skipped emptied.
        self.findings: dict[str, dict[str, Any]] = {}
        if self.path is not None and os.path.isfile(self.path):
            try:
                with open(self.path, encoding="utf-8") as fh:
                    data = json.load(fh)
                self.outputs = dict(data["outputs"])
            except (OSError, ValueError, KeyError, TypeError) as exc:
                logger.warning("%s: unreadable (%s): its outputs are redone", self.path, exc)
                self.outputs = {}
            else:  # findings that cannot be read are only missing from skipped rows
                found = data.get("findings") if isinstance(data, dict) else None
                self.findings = dict(found) if isinstance(found, dict) else {}

    def same_options(self, output: str | None, name: str) -> bool:
        """Whether ``output`` was made with these options (True when nothing is recorded)."""
        if self.outputs is None or output is None:
            return True
        before = self.outputs.get(os.path.basename(output))
        if before == self.options:
            return True
        if before is None:
            why = "not recorded as made by o3d_ofp"
        else:
            changed = [
                f"{k} {before.get(k)!r} -> {v!r}" for k, v in self.options.items()
                if before.get(k) != v
            ]  # fmt: skip
            why = (
                "made with other options: " + ", ".join(changed)
                if changed
                else "recorded by another version of o3d_ofp"
            )
        logger.info("%s: %s is redone (%s)", name, output, why)
        return False

    def add(self, output: str | None, *, result: TargetResult | None = None) -> None:
        """Record that ``output`` was just made with these options (and what was found)."""
        if self.path is None or output is None:
            return
        if self.outputs is None:
            self.outputs = {}
        key = os.path.basename(output)
        self.outputs[key] = self.options
        if result is not None:
            row = result.row()
            self.findings[key] = {k: row[k] for k in _FOUND}
        self._write()

    def found(self, output: str | None) -> dict[str, Any]:
        """Return what was found when ``output`` was made (empty when not recorded)."""
        if output is None:
            return {}
        row = self.findings.get(os.path.basename(output))
        if not isinstance(row, dict):
            return {}
        out: dict[str, Any] = {}
        for key in _FOUND:
            value = row.get(key)
            if key in ("warnings", "notes") and isinstance(value, list):
                out[key] = tuple(str(v) for v in value)
            elif key == "coverage" and isinstance(value, (int, float)):
                out[key] = float(value)
            elif key == "suspect" and isinstance(value, bool):
                out[key] = value
            elif key == "n_vertices" and isinstance(value, int):
                out[key] = value
            elif key == "kind" and value in ("colors", "texture", "detail"):
                out[key] = value
        return out

    def forget(self, outputs: Iterable[str | None]) -> None:
        """Drop the records of outputs about to be made again (written at once)."""
        if self.path is None:
            return
        if self.outputs is None:
            self.outputs = {}
        for output in outputs:
            if output is not None:
                self.outputs.pop(os.path.basename(output), None)
                self.findings.pop(os.path.basename(output), None)
        self._write()

    def _write(self) -> None:
        assert self.path is not None and self.outputs is not None
        data = {"version": 1, "outputs": self.outputs, "findings": self.findings}
        with atomic_path(self.path, suffix=".json") as tmp, open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=1, sort_keys=True)


#: The fields of a target's record kept for a rerun that skips its output.
_FOUND = ("kind", "coverage", "suspect", "n_vertices", "warnings", "notes")


def _up_to_date(output: str | None, inputs: Sequence[str | None]) -> bool:
    """Whether ``output`` exists and is newer than every input (all of them files)."""
    if output is None or any(p is None for p in inputs):
        return False
    try:
        done = os.stat(output).st_mtime_ns
        return all(done > os.stat(p).st_mtime_ns for p in inputs if p is not None)
    except OSError:
        return False


def _transfer_job(kind: str, cache_dir: Any, options: dict[str, Any]) -> TransferJob:
    """Return the job of a :func:`transfer_many` call, each option checked by its options object."""
    check_choice(kind, "kind", KINDS)
    known = (*_BASIS_OPTIONS, *_DETAIL_OPTIONS, *_JOB_OPTIONS)
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise OptionError(
            unknown[0], f"is not an option of transfer_many; it takes {', '.join(sorted(known))}"
        )
    given = {name: options[name] for name in _BASIS_OPTIONS if name in options}
    bases = BasisOptions(**given) if given else None
    detail = DetailOptions(**{n: options[n] for n in _DETAIL_OPTIONS if n in options})
    job = {name: options[name] for name in _JOB_OPTIONS if name in options}
    check_choice(job.get("map", "estimate"), "map", ("estimate", "identity"))
    check_choice(job.get("components", "auto"), "components", COMPONENTS)
    signal = check_choice(job.get("signal", "auto"), "signal", ("auto", "colors", "texture"))
    check_bool(job.get("strict", False), "strict")
    check_bool(job.get("atlas", False), "atlas")
    check_int(job.get("texture_size", 1024), name="texture_size", minimum=1,
              maximum=MAX_TEXTURE_SIZE)  # fmt: skip
    if kind == "texture" and signal == "colors":
        raise OptionError("signal", "'colors' does not apply to kind='texture' (a bake)")
    texture = job.get("texture")
    if texture is not None:
        if not isinstance(texture, (str, os.PathLike)):
            raise OptionError("texture", f"must be an image file path; got {type(texture).__name__}")
        job["texture"] = os.path.abspath(os.fspath(texture))
        if not os.path.isfile(job["texture"]):
            raise FileNotFoundError(f"texture {job['texture']}: no such image file")
        if kind == "detail" or signal == "colors":
            raise OptionError("texture", "(the source's texture image) applies to its colors or bake")
    return TransferJob(
        kind=kind, bases=bases, detail=detail,
        cache_dir=None if cache_dir is None else os.fspath(cache_dir), **job,
    )  # fmt: skip


def _source(source: Any, job: TransferJob) -> SharedSource:
    """Read the source and compute its bases, once for every target."""
    path = os.fspath(source) if isinstance(source, (str, os.PathLike)) else None
    geometry = read_geometry(path) if path is not None else source
    if not is_open3d_geometry(geometry):
        raise TypeError(f"source must be a file or an Open3D geometry; got {type(source).__name__}")
    name = os.path.basename(path) if path else "source"
    V, F = geometry_to_arrays(geometry)
    signal, texture = None, None
    if job.kind == "texture":
        try:
            texture = surface_colors(geometry, job.texture)
        except (TypeError, ValueError, FileNotFoundError) as exc:
            own = path is not None and job.texture is None
            why = no_texture_message(path, exc) if own else f"{name}: {exc}"
            raise ValueError(f"the source has no texture or vertex colors to bake: {why}") from exc
    if job.kind in ("colors", "texture"):
        signal = _source_colors(
            geometry, name, job.signal, quiet=job.kind == "texture", texture=job.texture
        )
    elif F is None:
        raise ValueError(f"{name}: the source of a detail transfer must be a triangle mesh")
    t0 = time.perf_counter()
    # The source's side of the plan, with any target: a source above the dense threshold has
    # its maps to mesh targets estimated on coarse copies (its coarse copy is made once).
    plan = plan_pair(
        V, F, None, None, task=job.task(), match=job.match, bases=job.bases, detail=job.detail,
        names=(name, "the target"),
    )  # fmt: skip
    eig, B, cached, coarse = prepare_source(plan, V, F, match=job.match, cache_dir=job.cache_dir)
    COUNTERS["source_bases"] += 1
    logger.info(
        "source %s: %d vertices, eigenbasis k=%d%s%s (%.1f s); shared with every target",
        name, V.shape[0], eig.k, " (cached)" if cached else "",
        "" if B is None else f", OFP basis {B.size} functions",
        time.perf_counter() - t0,
    )  # fmt: skip
    if coarse is not None:
        logger.info("source %s: coarse copy of %d vertices and its eigenbasis; shared with "
                    "every target", name, coarse.vertices.shape[0])  # fmt: skip
    return SharedSource(name, V, F, eig, B, signal, job, texture, coarse)


def _source_colors(
    geometry: Any, name: str, signal: str, *, quiet: bool = False, texture: str | None = None
) -> Any:
    """Return the source's colors per vertex: its vertex colors or its texture sampled there."""
    colors = vertex_colors(geometry) if signal in ("auto", "colors") and texture is None else None
    if colors is not None or signal == "colors":
        if colors is None:
            raise ValueError(f"{name}: the source has no vertex colors to transfer")
        return colors
    try:
        colors = texture_colors(geometry, texture)
    except (TypeError, ValueError, FileNotFoundError) as exc:
        raise ValueError(
            f"{name}: the source has no vertex colors and no usable texture ({exc})"
        ) from exc
    if signal == "auto" and not quiet:
        logger.info("%s: no vertex colors; transferring its texture sampled at its vertices", name)
    return colors


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
        nothing is written and each record keeps the values.
    cache_dir : str or os.PathLike, optional
        Eigenbasis and OFP-basis cache (see :mod:`o3d_ofp.workflows.cache`): a second run over
        the same shapes solves no eigenproblem again. Damaged entries are recomputed.
    workers : int, optional
        Processes of the local cluster (default: the cores of this machine, at most one per
        target); ``0`` runs in this process without Dask. Ignored with ``client``.
    skip_existing : bool, default True
        Skip (status ``"skipped"``) a target whose output is newer than both the source and
        the target files and was made with the same options (recorded in the output folder's
        :data:`OUTPUTS_RECORD`; never for inputs given as geometries).
    progress : bool, default True
        A progress bar over the targets on stderr when it is a terminal.
    **options
        ``map`` ("estimate" (default) or "identity": targets with the source's vertices),
        ``k1`` (29), ``k2`` (39), ``order`` (2), ``preset`` ("ours" for colors, "ours*" for
        detail), ``tol``, ``mode`` ("add", "replace-detail" or "coordinates", detail, see
        :func:`o3d_ofp.transfer_detail`), ``band`` (30, detail), ``amount`` (1.0, detail),
        ``components`` ("auto"), ``strict`` (False: a suspect map fails its target),
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
    ValueError, TypeError
        For bad options, an unreadable source or one without colors (before any work).
    ImportError
        When a cluster is needed and Dask is not installed.
    """
    job = _transfer_job(kind, cache_dir, options)
    items = _items(targets, "targets")
    out_dir = _run_options(output_dir, "output_dir", workers, client)
    with _output_folder(out_dir):
        names, outputs = _outputs(items, out_dir, kind)
        source_path = os.fspath(source) if isinstance(source, (str, os.PathLike)) else None
        if source_path is not None and not os.path.isfile(source_path):
            raise FileNotFoundError(f"{source_path}: no such source file")
        records: dict[int, TargetResult] = {}
        todo: list[int] = []
        made = _OutputsRecord(out_dir, job)
        for i, item in enumerate(items):
            path = item if isinstance(item, str) else None
            current = path is not None and _up_to_date(outputs[i], (source_path, path))
            if skip_existing and current and not made.same_options(outputs[i], names[i]):
                current = False
            if skip_existing and current:
                logger.info("%s: skipped: %s is newer than the source and the target and "
                            "made with the same options", names[i], outputs[i])  # fmt: skip
                records[i] = TargetResult(
                    **{"kind": kind, **made.found(outputs[i])},
                    index=i, name=names[i], path=path, status="skipped", output=outputs[i],
                )  # fmt: skip
            else:
                todo.append(i)
        if todo:
            shared = _source(source, job)
            specs = [_spec(i, items[i], names[i], outputs[i], kind) for i in todo]
            ready = [s for s in specs if isinstance(s, ShapeSpec)]
            for s in specs:
                if isinstance(s, TargetResult):
                    records[s.index] = s
            # The outputs about to be (re)made lose their record first: an interrupted run
            # leaves none of them said to be made with these options.
            made.forget(outputs[i] for i in todo)
            arrived = 0

            def on_record(r: TargetResult) -> None:
                nonlocal arrived
                records[r.index] = _finish_in_memory(r, items[r.index], outputs[r.index], kind)
                COUNTERS[f"target_eigenbases_{'cached' if r.cached else 'computed'}"] += r.ok
                if records[r.index].status == "ok":
                    made.add(outputs[r.index], result=records[r.index])
                    arrived += 1

            try:
                _run(
                    transfer_task, shared, ready, kind=kind, client=client, workers=workers,
                    progress=progress, on_record=on_record,
                )  # fmt: skip
            except KeyboardInterrupt:
                logger.warning(
                    "interrupted: %d of %d targets done%s", arrived, len(todo),
                    "; a rerun skips them and does the others" if out_dir else "",
                )  # fmt: skip
                raise
    results = [records[i] for i in range(len(items))]
    counts = Counter(r.status for r in results)
    logger.info("transfer_many (%s): %s", kind, dict(counts))
    return results


def _items(values: Any, name: str) -> list[Any]:
    """The shapes of a collection: files, folders (their mesh files) and geometries, checked."""
    if isinstance(values, (str, bytes, os.PathLike)) or is_open3d_geometry(values):
        raise OptionError(
            name, f"must be a list of shapes (files, folders or geometries); got one "
            f"{type(values).__name__} ({values!r}): pass [{values!r}]"
            if not is_open3d_geometry(values) else
            f"must be a list of shapes; got one {type(values).__name__}: pass [it]",
        )  # fmt: skip
    try:
        items = expand_paths(values)
    except TypeError as exc:
        raise OptionError(name, f"must be a list of shapes; got {type(values).__name__}") from exc
    if not items:
        raise OptionError(name, "holds no shapes (an empty list, or folders without mesh files)")
    return items


def _run_options(folder: Any, name: str, workers: Any, client: Any) -> str | None:
    """Check a run's folder (a folder, not a file) and ``workers``; return the folder's path."""
    if workers is not None:
        check_int(workers, name="workers", minimum=0)
        if workers == 0 and client is not None:
            raise OptionError("workers", "=0 runs in this process: give it or client=, not both")
    if folder is None:
        return None
    if not isinstance(folder, (str, os.PathLike)):
        raise OptionError(name, f"must be a folder path; got {type(folder).__name__}")
    path = os.fspath(folder)
    if os.path.exists(path) and not os.path.isdir(path):
        raise OptionError(name, f"{path} is a file; a folder is expected (made when missing)")
    return path


@contextlib.contextmanager
def _output_folder(out_dir: str | None) -> Iterator[None]:
    """Create the output folder (checked writable); removed again, if empty, on a failure.

    A read-only folder is refused before any work (it was found by the first target's write,
    after the source's eigensolve, and the summary could not be written either).
    """
    if out_dir is None:
        yield
        return
    with output_folder(out_dir):  # removed again if the run fails before writing anything
        if not os.access(out_dir, os.W_OK | os.X_OK):
            raise PermissionError(
                f"{out_dir}: the output folder cannot be written (read-only or no permission); "
                "choose another output folder"
            )
        yield


def _spec(i: int, item: Any, name: str, output: str | None, kind: str) -> ShapeSpec | TargetResult:
    """Return the task input of a target: a geometry is sent as arrays (written back here)."""
    if isinstance(item, str):
        return ShapeSpec(i, name, item, None, output)
    try:
        arrays = geometry_to_arrays(item)
    except (TypeError, ValueError) as exc:
        return failed(ShapeSpec(i, name, None), f"{type(exc).__name__}: {exc}", kind=kind)
    return ShapeSpec(i, name, None, arrays, None)


def _finish_in_memory(r: TargetResult, item: Any, output: str | None, kind: str) -> TargetResult:
    """Write the result of a target given as a geometry like that geometry (same kind)."""
    if isinstance(item, str) or r.status != "ok" or output is None:
        return r
    try:
        if kind == "colors":
            geometry = like_target(item, colors=r.values)
        else:
            geometry = like_target(item, vertices=r.values)
        write_geometry(output, geometry)
    except Exception as exc:  # a target's failure is its record, never the run's
        logger.warning("%s: failed to write %s: %s: %s", r.name, output, type(exc).__name__, exc)
        return dataclasses.replace(
            r, status="failed", error=f"{type(exc).__name__}: {exc}", values=None
        )
    return dataclasses.replace(r, output=output, values=None)


def bases_many(
    paths: Iterable[Any],
    *,
    cache_dir: str | os.PathLike[str],
    client: Any = None,
    k: int = 29,
    order: int = 2,
    preset: str | None = "ours",
    tol: float | None = None,
    components: str = "auto",
    eigenbasis_k: int | None = ESTIMATION_K,
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
    for name, value in (("k", k), ("order", order), ("eigenbasis_k", eigenbasis_k)):
        if value is not None:
            check_int(value, name=name, minimum=1)
    check_choice(components, "components", COMPONENTS)
    resolve_tol(tol, preset)
    items = _items(paths, "paths")
    folder = _run_options(cache_dir, "cache_dir", workers, client)
    assert folder is not None
    os.makedirs(folder, exist_ok=True)
    job = BasisJob(
        cache_dir=folder, k=k, order=order, tol=tol, preset=preset if tol is None else None,
        components=components, eigenbasis_k=eigenbasis_k,
    )  # fmt: skip
    names, _ = _outputs(items, None, "basis")
    specs = [_spec(i, item, names[i], None, "basis") for i, item in enumerate(items)]
    records = {s.index: s for s in specs if isinstance(s, TargetResult)}
    ready = [s for s in specs if isinstance(s, ShapeSpec)]
    for r in _run(
        basis_task, job, ready, kind="basis", client=client, workers=workers, progress=progress
    ):
        records[r.index] = r
    results = [records[i] for i in range(len(items))]
    logger.info("bases_many: %s", dict(Counter(r.status for r in results)))
    return results
