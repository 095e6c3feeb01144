"""Independent jobs side by side on the machine's cores: the extra ones in forked processes.

The two eigensolves of a pair (and the coarse copies of the dense path) are independent and
mostly single-threaded: SciPy's ARPACK loop holds the GIL between its steps, so Python
threads do not overlap them (measured: two 27.5k-vertex eigenbases, k = 99, 6.7 s in two
threads, 6.8 s one after the other). :func:`side_by_side` runs the first job here and each
of the others in a child process started with ``fork`` (2 cores: 4.0-4.4 s for the same two).

Only ``fork`` is used, and only where it is the platform's own method (Linux): the child
starts in a few milliseconds from the parent's memory, and the job needs no pickling.
``spawn`` and ``forkserver`` re-import the caller's ``__main__`` (a script without the
``if __name__ == "__main__":`` guard then fails) and pay the imports again (0.5-1 s); where
``fork`` is not available, or in a daemonic process (a Dask worker cannot have children), or
from a thread other than the main one or while other (non-daemon) threads run (a fork can
catch them inside OpenBLAS, whose fork handler then waits forever), or on one core, or when
memory is short, or when a process cannot be started, the jobs run one after the other here.
``O3D_OFP_PROCESSES=1`` in the environment does the same (the number of jobs at once).

Each child has one pipe to this process, read by a thread here as it is written: the
child's log records, handed to this process's logger of the same name as they happen, then
its answer (its value or its exception, and the warnings it issued, issued here again). No
lock is shared between the processes, so a child ended at any moment cannot block this one.
A child that ends without an answer (killed for memory, say) is said and its job is run
here; an error or an interrupt here ends the children, and a child dies with its parent
(``PR_SET_PDEATHSIG``) instead of computing on for nobody.
"""

from __future__ import annotations

import ctypes
import logging
import logging.handlers
import multiprocessing
import os
import pickle
import signal
import sys
import threading
import traceback
import warnings
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from ._memory import available_memory, format_bytes
from ._warnings import OFPWarning, reissue

__all__ = ["ENVIRONMENT", "processes_available", "side_by_side"]

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: Environment variable: the most jobs run at once (``1``: never a child process).
ENVIRONMENT = "O3D_OFP_PROCESSES"


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
    the process is inside a BLAS call (a new-user trial: ``ofp.match`` from three threads at
    once hung in 2 of 4 runs). Forks are made from the main thread while every other thread
    is a daemon (a notebook kernel's, a progress bar's); a caller that runs its own threads
    has its cores busy already.
    """
    here = threading.current_thread()
    if here is not threading.main_thread():
        return True
    return any(t is not here and not t.daemon and t.is_alive() for t in threading.enumerate())


class _Pipe:
    """The ``put_nowait`` a :class:`logging.handlers.QueueHandler` needs, over the child's pipe."""

    def __init__(self, conn: Any) -> None:
        self.conn = conn
        self.lock = threading.Lock()  # a job may log from several threads of the child

    def send(self, message: tuple[Any, ...]) -> None:
        data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        with self.lock:
            self.conn.send_bytes(data)

    def put_nowait(self, record: logging.LogRecord) -> None:
        self.send(("log", record))


def _die_with_parent(parent: int) -> None:
    """Have the kernel end this child when the process that forked it ends (Linux)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - no prctl: the pipe still breaks
        pass
    if os.getppid() != parent:  # it ended before the call above
        os._exit(1)


def _child(job: Callable[[], Any], conn: Any, unused: Any, parent: int) -> None:
    """Run ``job`` in the forked child; send its records, then its answer, through ``conn``."""
    unused.close()  # our copy of the reading end: the parent's death must break the pipe
    _die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent takes Ctrl-C and ends us
    pipe = _Pipe(conn)
    # Every record leaves at the logger it was made on, before any handler here sees it: the
    # parent hands it to its logger of that name, whose handlers, propagation and filters
    # (the command line's handler on "o3d_ofp", which does not propagate; a caller's on the
    # root) then treat it exactly as a record made there. Patched on the class: this process
    # is the child's alone and ends with the job.
    sender = logging.handlers.QueueHandler(pipe)  # type: ignore[arg-type]
    logging.Logger.callHandlers = lambda self, record: sender.handle(record)  # type: ignore
    with warnings.catch_warnings(record=True) as caught:  # the filters inherited decide
        try:
            outcome: tuple[Any, ...] = ("ok", job())
        except BaseException as exc:  # every failure is the parent's to raise
            outcome = ("error", exc, "".join(traceback.format_exception(exc)))
    said = [(str(w.message), w.category, w.filename, w.lineno) for w in caught]
    try:
        data = pickle.dumps(("answer", outcome, said), protocol=pickle.HIGHEST_PROTOCOL)
        if outcome[0] == "error":
            pickle.loads(data)  # an exception that cannot be rebuilt there is sent as text
    except Exception:
        text = outcome[2] if outcome[0] == "error" else traceback.format_exc()
        failure = RuntimeError(f"a side process failed and its answer could not be sent:\n{text}")
        data = pickle.dumps(("answer", ("error", failure, text), said))
    with pipe.lock:
        conn.send_bytes(data)
    conn.close()


def _dispatch(record: logging.LogRecord) -> None:
    target = logging.getLogger(record.name)
    if target.isEnabledFor(record.levelno):
        target.handle(record)


class _Reader(threading.Thread):
    """Read one child's pipe here: log records as they come, then the answer (or the end)."""

    def __init__(self, receive: Any, what: str) -> None:
        super().__init__(name=f"o3d_ofp {what} reader", daemon=True)
        self.receive = receive
        self.answer: tuple[Any, ...] | None = None

    def run(self) -> None:
        while True:
            try:
                message = pickle.loads(self.receive.recv_bytes())
            except (EOFError, OSError):  # the child ended (without an answer if none came)
                return
            except Exception as exc:  # a record cut short by a killed child
                logger.debug("a message from a side process could not be read: %s", exc)
                return
            if message[0] == "log":
                _dispatch(message[1])
            else:
                self.answer = message[1:]
                return


def _issue(said: list[tuple[str, type[Warning], str, int]]) -> None:
    """Issue here the warnings a child issued: ours at the caller's line, others at theirs."""
    for message, category, filename, lineno in said:
        if issubclass(category, OFPWarning):
            reissue(message, category)
        else:  # where it was raised: the filters here (by module, by category) apply as there
            warnings.warn_explicit(message, category, filename, lineno)


def _start(
    ctx: Any, job: Callable[[], Any], what: str, index: int
) -> tuple[Any, _Reader] | None:
    """Fork a child for ``job`` and its reader; None (said) when a process cannot be made."""
    try:
        receive, send = ctx.Pipe(duplex=False)
    except OSError as exc:
        logger.warning("%s: no pipe for a side process (%s); running here", what, exc)
        return None
    process = ctx.Process(
        target=_child,
        args=(job, send, receive, os.getpid()),
        name=f"o3d_ofp {what} {index}",
        daemon=True,
    )
    try:
        process.start()
    except OSError as exc:
        receive.close()
        send.close()
        logger.warning("%s: a side process could not start (%s); running here", what, exc)
        return None
    send.close()  # ours closed: the child's end without an answer is an EOF here
    reader = _Reader(receive, what)
    reader.start()
    return process, reader


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
        The first job's exception, in the order of ``jobs``, raised here (a child's carries
        its traceback there as a note).
    """
    jobs = list(jobs)
    at_once = min(len(jobs), processes_available())
    if at_once > 1 and memory_each is not None:
        free = available_memory()
        if free is not None and free < at_once * memory_each:
            fits = max(1, int(free // max(memory_each, 1.0)))
            if fits < at_once:
                logger.info(  # the only sign that memory made the run slower
                    "%s: %s available, about %s each: %d at once",
                    what,
                    format_bytes(free),
                    format_bytes(memory_each),
                    fits,
                )
                at_once = fits
    if at_once <= 1:
        return [job() for job in jobs]
    logger.debug("%s: %d at once (%d in forked processes)", what, at_once, at_once - 1)
    ctx = multiprocessing.get_context("fork")
    children: dict[int, tuple[Any, _Reader]] = {}
    results: dict[int, T] = {}
    try:
        for index in range(1, at_once):
            started = _start(ctx, jobs[index], what, index)
            if started is None:
                break
            children[index] = started
        for index in range(len(jobs)):
            if index not in children:
                results[index] = jobs[index]()
        for index, (process, reader) in children.items():
            reader.join()
            if reader.answer is None:
                process.join()
                logger.warning(
                    "%s: the process of job %d ended without an answer (exit code %s: out of "
                    "memory?); running it here",
                    what,
                    index + 1,
                    process.exitcode,
                )
                results[index] = jobs[index]()
                continue
            outcome, said = reader.answer
            _issue(said)
            if outcome[0] == "error":
                exc = outcome[1]
                if hasattr(exc, "add_note"):  # Python 3.11+
                    exc.add_note(f"in the side process computing {what}:\n{outcome[2]}")
                raise exc
            results[index] = outcome[1]
    finally:
        for process, reader in children.values():
            if reader.answer is None:  # an error or an interrupt here: its work is moot
                process.terminate()
            process.join()
            reader.join()  # at the child's end, its pipe gives EOF
            reader.receive.close()
    return [results[i] for i in range(len(jobs))]
