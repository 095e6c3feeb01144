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
on one core, or when memory is short, the jobs run one after the other here, as before.
``O3D_OFP_PROCESSES=1`` in the environment does the same (the number of jobs at once).

A child's log records are sent to this process's loggers as they happen, its warnings are
issued here when it ends, and its exception is raised here. A child that dies without an
answer (killed for memory, say) is said and its job is run here instead. An interrupt or an
error here ends the children.
"""

from __future__ import annotations

import logging
import logging.handlers
import multiprocessing
import os
import pickle
import signal
import sys
import traceback
import warnings
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from ._memory import available_memory, format_bytes
from ._warnings import reissue

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
    limit = _cores()
    setting = os.environ.get(ENVIRONMENT, "").strip()
    if setting:
        try:
            limit = min(limit, max(1, int(setting)))
        except ValueError:
            logger.warning("%s=%r is not a whole number: ignored", ENVIRONMENT, setting)
    return limit


class _Dispatch(logging.Handler):
    """Hand a child's record to this process's logger of the same name."""

    def handle(self, record: logging.LogRecord) -> bool:  # type: ignore[override]
        target = logging.getLogger(record.name)
        if target.isEnabledFor(record.levelno):
            target.handle(record)
        return True

    def emit(self, record: logging.LogRecord) -> None:  # pragma: no cover - handle() does it
        pass


def _child(job: Callable[[], Any], conn: Any, log_queue: Any) -> None:
    """Run ``job`` in the forked child; send back (status, value, warnings) as one pickle."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent takes Ctrl-C and ends us
    # Every record leaves at the logger it was made on, before any handler here sees it: the
    # parent hands it to its logger of that name, whose handlers, propagation and filters
    # (the command line's handler on "o3d_ofp", which does not propagate; a caller's on the
    # root) then treat it exactly as a record made there. Patched on the class: this process
    # is the child's alone and ends with the job.
    sender = logging.handlers.QueueHandler(log_queue)
    logging.Logger.callHandlers = lambda self, record: sender.handle(record)  # type: ignore
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # the parent's filters decide when it issues them
        try:
            outcome: tuple[str, Any] = ("ok", job())
        except BaseException as exc:
            outcome = ("error", exc)
    said = [(str(w.message), w.category) for w in caught]
    try:
        data = pickle.dumps((outcome, said), protocol=pickle.HIGHEST_PROTOCOL)
        if outcome[0] == "error":
            pickle.loads(data)  # an exception that cannot be rebuilt there is sent as text
    except Exception:
        text = "".join(traceback.format_exception(outcome[1])) if outcome[0] == "error" else ""
        failure = RuntimeError(f"a side process failed and its answer could not be sent:\n{text}")
        data = pickle.dumps((("error", failure), said))
    conn.send_bytes(data)
    conn.close()


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
        Estimated peak bytes of one job: no more jobs run at once than the available memory
        holds (each beyond the first needs its own).

    Returns
    -------
    list
        The jobs' values, in order.

    Raises
    ------
    BaseException
        The first job's exception, in the order of ``jobs``, raised here.
    """
    jobs = list(jobs)
    at_once = min(len(jobs), processes_available())
    if at_once > 1 and memory_each is not None:
        free = available_memory()
        if free is not None and free < at_once * memory_each:
            fits = max(1, int(free // max(memory_each, 1.0)))
            if fits < at_once:
                logger.info(
                    "%s: %s available, about %s each: %d at once",
                    what,
                    format_bytes(free),
                    format_bytes(memory_each),
                    fits,
                )
                at_once = fits
    if at_once <= 1:
        return [job() for job in jobs]
    logger.info("%s: %d at once (%d in forked processes)", what, at_once, at_once - 1)
    ctx = multiprocessing.get_context("fork")
    log_queue = ctx.Queue()
    listener = logging.handlers.QueueListener(log_queue, _Dispatch())
    children: list[tuple[int, Any, Any]] = []  # (job index, process, receiving end)
    results: dict[int, T] = {}
    answered: set[int] = set()
    listening = False
    try:
        for index in range(1, at_once):
            receive, send = ctx.Pipe(duplex=False)
            process = ctx.Process(
                target=_child,
                args=(jobs[index], send, log_queue),
                name=f"o3d_ofp {what} {index}",
                daemon=True,
            )
            process.start()
            send.close()  # ours closed: the child's exit without an answer is an EOF here
            children.append((index, process, receive))
        listener.start()
        listening = True
        results[0] = jobs[0]()
        for index in range(at_once, len(jobs)):
            results[index] = jobs[index]()
        for index, process, receive in children:
            try:
                outcome, said = pickle.loads(receive.recv_bytes())
                answered.add(index)
            except EOFError:
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
            for message, category in said:
                reissue(message, category)
            if outcome[0] == "error":
                raise outcome[1]
            results[index] = outcome[1]
    finally:
        for index, process, receive in children:
            if index not in answered:  # an interrupt or an error here: the child's work is moot
                process.terminate()
            process.join()
            receive.close()
        if listening:
            listener.stop()
        log_queue.close()
        log_queue.join_thread()
    return [results[i] for i in range(len(jobs))]
