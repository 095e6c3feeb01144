"""Independent jobs side by side on the machine's cores: the extra ones in forked processes.

The two eigensolves of a pair (and the coarse copies of the dense path) are independent and
mostly single-threaded: SciPy's ARPACK loop holds the GIL between its steps, so Python
threads do not overlap them (measured: two 27.5k-vertex eigenbases, k = 99, 6.7 s in two
threads, 6.8 s one after the other). :func:`side_by_side` runs the first job here and the
others in a :class:`concurrent.futures.ProcessPoolExecutor` whose processes are forked
(2 cores: 4.0-4.4 s for the same two).

Only ``fork`` is used, and only where it is the platform's own method (Linux): a child
starts in a few milliseconds from the parent's memory, and the jobs reach it without
pickling (through the pool's initializer; only the answers are pickled). ``spawn`` and
``forkserver`` re-import the caller's ``__main__`` (a script without the
``if __name__ == "__main__":`` guard then fails) and pay the imports again (0.5-1 s); where
``fork`` is not available, or in a daemonic process (a Dask worker cannot have children), or
from a thread other than the main one or while other (non-daemon) threads run (a fork can
catch them inside OpenBLAS, whose fork handler then waits forever), or on one core, or when
memory is short, or when a process cannot be started, the jobs run one after the other here.
``O3D_OFP_PROCESSES=1`` in the environment does the same (the number of jobs at once).

The children's log records come here through one pipe as they are made and are handed to
this process's logger of the same name; the warnings a child issued come with its answer and
are issued here again. A child that ends without an answer (killed for memory, say) breaks
the pool: that is said, and its job (with any other that the pool's end left without an
answer) is run here. An error or an interrupt here ends the children.
"""

from __future__ import annotations

import ctypes
import logging
import logging.handlers
import multiprocessing
import os
import signal
import sys
import threading
import traceback
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import reduction
from types import SimpleNamespace
from typing import Any, TypeVar

from ._memory import available_memory, format_bytes
from ._warnings import OFPWarning, reissue

__all__ = ["ENVIRONMENT", "processes_available", "side_by_side"]

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: Environment variable: the most jobs run at once (``1``: never a child process).
ENVIRONMENT = "O3D_OFP_PROCESSES"

_JOBS: Sequence[Callable[[], Any]] = ()  # in a child: the jobs of its pool


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def processes_available() -> int:
    """How many jobs :func:`side_by_side` may run at once here (1: all in this process)."""
    if not sys.platform.startswith("linux"):
        return 1
    if "fork" not in multiprocessing.get_all_start_methods():  # pragma: no cover
        return 1
    if multiprocessing.current_process().daemon:  # a daemonic process cannot have children
        return 1
    if _other_threads_at_work():
        return 1
    limit = _cores()
    setting = os.environ.get(ENVIRONMENT, "").strip()
    if setting:
        try:
            value = int(setting)
        except ValueError:
            logger.warning("%s=%r is not a whole number: ignored", ENVIRONMENT, setting)
        else:
            if value < 1:
                logger.warning("%s=%s: taken as 1 (one job at a time)", ENVIRONMENT, value)
            limit = min(limit, max(1, value))
    return limit


def _other_threads_at_work() -> bool:
    """Whether a fork could catch another thread inside a library: then none is made.

    OpenBLAS's fork handler waits for its threads to stop, forever when another thread of
    the process is inside a BLAS call (``ofp.match`` from three threads at once can hang).
    Forks are made from the main thread while every other thread
    is a daemon (a notebook kernel's, a progress bar's); a caller that runs its own threads
    has its cores busy already.
    """
    here = threading.current_thread()
    if here is not threading.main_thread():
        return True
    return any(t is not here and not t.daemon and t.is_alive() for t in threading.enumerate())


def _start_child(jobs: Sequence[Callable[[], Any]], send: Any, turn: Any, parent: int) -> None:
    """Set up a forked child of the pool: its jobs, its log records sent here, its end."""
    global _JOBS
    _JOBS = jobs
    # A pool's children keep copies of the ends of its pipes, so a parent killed without its
    # clean-up (SIGKILL, a batch scheduler's) would leave them waiting for work forever: the
    # kernel ends each child when the thread that forked it (the main one) ends.
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:  # it ended before the call above
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's, which ends us
    os.environ[ENVIRONMENT] = "1"  # a job's own side_by_side runs here: the cores are taken
    # What this process sends is pickled with protocol 5, an array's data written out once;
    # the pool's (4, before Python 3.14) copies it first: one more copy of the answer at the
    # child's peak (measured: 632 MB instead of 441 for a 200 MB answer; +26 ms for 22 MB).
    dumps = reduction.ForkingPickler.dumps
    reduction.ForkingPickler.dumps = staticmethod(lambda obj, protocol=None: dumps(obj, 5))

    def put_nowait(record: logging.LogRecord) -> None:
        with turn:  # the children take turns: a record longer than one write must stay whole
            send.send(record)

    # Every record leaves at the logger it was made on, before any handler here sees it: the
    # parent hands it to its logger of that name, whose handlers, propagation and filters
    # (the command line's handler on "o3d_ofp", which does not propagate; a caller's on the
    # root) then treat it exactly as a record made there. Patched on the class: this process
    # is the pool's alone and ends with it.
    sender = logging.handlers.QueueHandler(SimpleNamespace(put_nowait=put_nowait))  # type: ignore
    logging.Logger.callHandlers = lambda self, record: sender.handle(record)  # type: ignore


def _child_job(index: int) -> tuple[Any, Exception | None, list[tuple[Any, ...]]]:
    """Run job ``index`` in a child: its value or its exception, and the warnings it issued."""
    value, error = None, None
    with warnings.catch_warnings(record=True) as caught:  # the filters inherited decide
        try:
            value = _JOBS[index]()
        except Exception as exc:  # raised in the parent, with its traceback here as a note
            if hasattr(exc, "add_note"):  # Python 3.11+
                exc.add_note(f"in a side process:\n{traceback.format_exc()}")
            error = exc
    return value, error, [(str(w.message), w.category, w.filename, w.lineno) for w in caught]


def _forward(receive: Any) -> None:
    """Hand each record a child sends to this process's logger of its name, until all end."""
    with receive:
        while True:
            try:
                record = receive.recv()
            except Exception:  # every child has ended (or one was killed within a record)
                return
            target = logging.getLogger(record.name)
            if target.isEnabledFor(record.levelno):
                target.handle(record)


def _issue(said: list[tuple[str, type[Warning], str, int]]) -> None:
    """Issue here the warnings a child issued: ours at the caller's line, others at theirs."""
    for message, category, filename, lineno in said:
        if issubclass(category, OFPWarning):
            reissue(message, category)
        else:  # where it was raised: the filters here (by module, by category) apply as there
            warnings.warn_explicit(message, category, filename, lineno)


def _end(processes: list[Any], answers: Any) -> None:
    """End the children now, and let the pool see the end of its pipe of answers.

    The pool reads an answer to its last byte: one cut short by a child's death (killed while
    it sends a large answer) keeps it, and the future, waiting until every write end of that
    pipe is closed. The children's close as they die; this process's, which it never writes
    on, is closed here (the pool has no public handle on it).
    """
    for process in processes:
        process.terminate()
    answers._writer.close()


def _answer(future: Future, processes: list[Any], answers: Any) -> Any:
    """Return a child's value, its warnings issued here, or raise its exception here."""
    while not wait([future], timeout=1.0).done:  # and every second, a look at the children
        if any(process.exitcode is not None for process in processes):
            _end(processes, answers)  # a dead child: ended, the pool settles every future
    value, error, said = future.result()
    _issue(said)
    if error is not None:
        raise error
    return value


def _start(ctx: Any, jobs: list[Callable[[], Any]], workers: int, what: str) -> Any:
    """Start the pool on ``jobs[1:]``: it, their futures and the reader of the children's records.

    None (said) when it cannot start: no process or no memory left for one, no semaphores
    (no ``/dev/shm``).
    """
    pool = None
    try:
        receive, send = ctx.Pipe(duplex=False)
        with send:  # this process's end closed: the pipe ends when every child has ended
            start = (jobs, send, ctx.Lock(), os.getpid())
            pool = ProcessPoolExecutor(workers, ctx, initializer=_start_child, initargs=start)
            futures = {index: pool.submit(_child_job, index) for index in range(1, len(jobs))}
        # Every child is forked now (at the submits), while no thread of this module runs.
        reader = threading.Thread(target=_forward, args=(receive,), name="o3d_ofp log", daemon=True)
        reader.start()
        return pool, futures, reader
    except OSError as exc:
        logger.warning("%s: a side process could not start (%s); running here", what, exc)
        if pool is not None:
            _end(list(pool._processes.values()), pool._result_queue)
            pool.shutdown(cancel_futures=True)
        return None


def side_by_side(
    jobs: Sequence[Callable[[], T]],
    *,
    what: str,
    memory_each: float | None = None,
) -> list[T]:
    """Run independent jobs, up to one per core: the first here, others in forked children.

    Parameters
    ----------
    jobs : sequence of callables without arguments
        Each returns a picklable value (sent back from its child). They must not depend on
        each other or change this process's state (a child's changes stay in the child).
    what : str
        What the jobs compute, for the log (e.g. ``"eigenbases"``).
    memory_each : float, optional
        Estimated peak bytes of one job, its answer's copies included: no more jobs run at
        once than the available memory holds that many times.

    Returns
    -------
    list
        The jobs' values, in order.

    Raises
    ------
    BaseException
        A job's exception, raised here: those of the jobs run here first, then the
        children's in the order of ``jobs`` (a child's carries its traceback there as a
        note, Python 3.11+).
    """
    jobs = list(jobs)
    at_once = min(len(jobs), processes_available())
    if at_once > 1 and memory_each is not None:
        free = available_memory()
        if free is not None and free < at_once * memory_each:
            at_once = max(1, int(free // max(memory_each, 1.0)))  # fewer: free < at_once * each
            logger.info(  # the only sign that memory made the run slower
                "%s: %s available, about %s each: %d at once",
                what,
                format_bytes(free),
                format_bytes(memory_each),
                at_once,
            )
    started = None
    if at_once > 1:
        logger.debug("%s: %d at once (%d in forked processes)", what, at_once, at_once - 1)
        started = _start(multiprocessing.get_context("fork"), jobs, at_once - 1, what)
    if started is None:
        return [job() for job in jobs]
    pool, futures, reader = started
    processes, answers = list(pool._processes.values()), pool._result_queue
    results: dict[int, Any] = {}
    try:
        # Jobs 1 to at_once - 1 are the children's; the others wait in the pool's queue, and
        # this process takes back, after its first job, those no child has begun.
        for index in range(len(jobs)):
            if index == 0 or (index >= at_once and futures[index].cancel()):
                results[index] = jobs[index]()
        for index, future in futures.items():
            if index in results:
                continue
            try:
                results[index] = _answer(future, processes, answers)
            except BrokenProcessPool:
                logger.warning(
                    "%s: the process of job %d ended without an answer (out of memory?); "
                    "running it here",
                    what,
                    index + 1,
                )
                results[index] = jobs[index]()
    except BaseException:  # an error or an interrupt here: the children's work is moot
        _end(processes, answers)
        raise
    finally:
        pool.shutdown(cancel_futures=True)
        reader.join()  # the children have ended: the pipe of records gives its end
    return [results[i] for i in range(len(jobs))]
