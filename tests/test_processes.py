"""Jobs side by side in forked processes (o3d_ofp.core._processes) and the eigenbases on them."""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.context
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from o3d_ofp.core import _processes
from o3d_ofp.core._processes import ENVIRONMENT, processes_available, side_by_side
from o3d_ofp.core._warnings import OFPWarning, collected_warnings, warn
from o3d_ofp.workflows import eigenbases as eigenbases_module

needs_two = pytest.mark.skipif(
    processes_available() < 2, reason="one core, not Linux, or O3D_OFP_PROCESSES=1: no children"
)
logger = logging.getLogger("o3d_ofp.tests.processes")


@pytest.fixture(autouse=True)
def _free_environment(monkeypatch):
    monkeypatch.delenv(ENVIRONMENT, raising=False)


@needs_two
def test_the_second_job_runs_in_another_process_and_values_keep_their_order():
    values = side_by_side([os.getpid, os.getpid], what="pids")
    assert values[0] == os.getpid()
    assert values[1] != os.getpid()  # a child: the job did not run here


def test_one_allowed_process_runs_every_job_here(monkeypatch):
    monkeypatch.setenv(ENVIRONMENT, "1")
    assert processes_available() == 1
    assert side_by_side([os.getpid, os.getpid, os.getpid], what="pids") == [os.getpid()] * 3


def test_a_setting_that_is_not_a_number_is_said_and_ignored(monkeypatch, caplog):
    monkeypatch.setenv(ENVIRONMENT, "two")
    with caplog.at_level(logging.WARNING, logger="o3d_ofp"):
        processes_available()
    assert f"{ENVIRONMENT}='two' is not a whole number" in caplog.text


@needs_two
def test_more_jobs_than_cores_all_run_in_order():
    jobs = [lambda i=i: i * i for i in range(5)]
    assert side_by_side(jobs, what="squares") == [0, 1, 4, 9, 16]
    pids = side_by_side([os.getpid] * 5, what="pids")
    assert pids[0] == os.getpid() and pids[1] != os.getpid()  # the second is a child's always


@needs_two
def test_a_job_own_side_by_side_runs_in_its_child_one_after_the_other():
    def nested() -> list[int]:
        return side_by_side([os.getpid, os.getpid], what="nested")

    here, there = side_by_side([os.getpid, nested], what="outer")
    assert there[0] != here and there == [there[0]] * 2  # no grandchild: the cores are taken


def _fail() -> None:
    raise ValueError("the child's own message")


@needs_two
def test_a_child_exception_is_raised_here_with_its_type_and_message():
    with pytest.raises(ValueError, match="the child's own message") as raised:
        side_by_side([lambda: 1, _fail], what="failing")
    notes = "".join(getattr(raised.value, "__notes__", []))
    if sys.version_info >= (3, 11):  # its traceback there comes along as a note
        assert "in a side process" in notes and "in _fail" in notes


class _Unpicklable(Exception):
    def __init__(self, a, b):
        super().__init__(f"{a} and {b}")


def _fail_unpicklable() -> None:
    raise _Unpicklable(1, 2)  # rebuilt with one argument by pickle: fails


@needs_two
def test_an_exception_that_cannot_travel_is_raised_by_its_job_run_here(caplog):
    with caplog.at_level(logging.WARNING, logger="o3d_ofp"):
        with pytest.raises(_Unpicklable, match="1 and 2") as raised:
            side_by_side([lambda: 1, _fail_unpicklable], what="failing")
    assert "job 2 ended without an answer" in caplog.text  # the pool could not read it
    assert not getattr(raised.value, "__notes__", [])  # raised here, not in a child


def _refuse() -> None:
    from o3d_ofp.core.wording import AdvisedError, Said

    raise AdvisedError(Said("the shape has {n} pieces", {"n": 3}, "components"))


def _refuse_option() -> None:
    from o3d_ofp.core.wording import OptionError

    raise OptionError("coarse_vertices", "must be >= 200; got 3")


@needs_two
def test_the_library_refusals_travel_back_from_a_child(caplog):
    """A refusal in a side process is raised here as it was, not taken for a lost child.

    They could not be rebuilt from their text: the caller saw "ended without an answer (out
    of memory?)" and the job ran again here (a large STL's coarse copy, refused twice).
    """
    from o3d_ofp.core.wording import AdvisedError, OptionError

    with caplog.at_level(logging.WARNING, logger="o3d_ofp"):
        with pytest.raises(AdvisedError, match="the shape has 3 pieces") as raised:
            side_by_side([lambda: 1, _refuse], what="refusing")
        assert raised.value.said.code == "components"
        with pytest.raises(OptionError, match="coarse_vertices must be >= 200") as refused:
            side_by_side([lambda: 1, _refuse_option], what="refusing")
        assert refused.value.option == "coarse_vertices"
    assert "without an answer" not in caplog.text
    if sys.version_info >= (3, 11):  # raised there: its traceback comes along as a note
        assert "in a side process" in "".join(getattr(raised.value, "__notes__", []))


def _warn_and_log() -> int:
    logger.info("from the child %d", 7)
    warn(logging.getLogger("o3d_ofp.tests.processes"), "a doubtful child result")
    warnings.warn("a plain warning", RuntimeWarning, stacklevel=1)  # _PLAIN_LINE
    return 3


with open(__file__, encoding="utf-8") as _source:
    _PLAIN_LINE = next(
        i for i, line in enumerate(_source, 1) if "# _PLAIN_LINE" in line and "warn(" in line
    )


@needs_two
def test_a_child_warnings_and_log_records_reach_this_process(caplog):
    from o3d_ofp.core._warnings import warnings_logged

    # logged at WARNING as the command line sets it (the forked child inherits the level)
    with caplog.at_level(logging.INFO, logger="o3d_ofp"), collected_warnings() as said:
        with pytest.warns(OFPWarning, match="a doubtful child result"), warnings_logged():
            with pytest.warns(RuntimeWarning, match="a plain warning"):
                assert side_by_side([lambda: 1, _warn_and_log], what="warning") == [1, 3]
    assert said == ["a doubtful child result"]
    records = [r for r in caplog.records if r.name == "o3d_ofp.tests.processes"]
    # a plain warning keeps the place it was raised in the child (the filters by module apply)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        side_by_side([lambda: 1, _warn_and_log], what="warning")
    plain = next(w for w in caught if w.category is RuntimeWarning)
    assert (plain.filename, plain.lineno) == (__file__, _PLAIN_LINE)
    assert [r.getMessage() for r in records][:1] == ["from the child 7"]
    assert any(r.levelno == logging.WARNING for r in records)


def _warn_and_fail() -> None:
    warn(logging.getLogger("o3d_ofp.tests.processes"), "said before failing")
    _fail()


@needs_two
def test_a_failing_child_warnings_are_issued_here_before_its_exception():
    with collected_warnings() as said, pytest.warns(OFPWarning, match="said before failing"):
        with pytest.raises(ValueError, match="the child's own message"):
            side_by_side([lambda: 1, _warn_and_fail], what="failing")
    assert said == ["said before failing"]


@needs_two
def test_a_child_record_reaches_each_handler_once_as_the_command_line_sets_them(monkeypatch):
    """The CLI's handler sits on "o3d_ofp", which does not propagate; a caller's on the root."""
    seen: dict[str, list[str]] = {"package": [], "root": []}

    class Keep(logging.Handler):
        def __init__(self, where: str):
            super().__init__(logging.DEBUG)
            self.where = where

        def emit(self, record: logging.LogRecord) -> None:
            seen[self.where].append(record.getMessage())

    package, root = logging.getLogger("o3d_ofp"), logging.getLogger()
    on_package, on_root = Keep("package"), Keep("root")
    monkeypatch.setattr(package, "level", logging.INFO)
    for propagate, expected_root in ((False, []), (True, ["from the child 7"])):
        seen["package"].clear()
        seen["root"].clear()
        monkeypatch.setattr(package, "propagate", propagate)
        package.addHandler(on_package)
        root.addHandler(on_root)
        try:
            side_by_side([lambda: 1, _log_only], what="logging")
        finally:
            package.removeHandler(on_package)
            root.removeHandler(on_root)
        from_child = [m for m in seen["package"] if m.startswith("from the child")]
        assert from_child == ["from the child 7"]  # once, not lost
        assert [m for m in seen["root"] if m.startswith("from the child")] == expected_root


def _log_only() -> int:
    logger.info("from the child %d", 7)
    return 2


@needs_two
def test_a_child_that_dies_is_said_and_its_job_is_run_here(caplog):
    parent = os.getpid()

    def dies_in_a_child() -> str:
        if os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)  # as the kernel's out-of-memory killer does
        return "here"

    with caplog.at_level(logging.WARNING, logger="o3d_ofp"):
        assert side_by_side([lambda: 1, dies_in_a_child], what="dying") == [1, "here"]
    assert "dying: the process of job 2 ended without an answer" in caplog.text


@needs_two
def test_a_child_killed_in_the_middle_of_its_answer_does_not_hang(tmp_path):
    """The pool reads an answer to its end: a cut one must not keep it waiting forever."""
    result = _run_script(
        """
        import logging, os, signal
        from multiprocessing import connection
        from o3d_ofp.core._processes import side_by_side

        logging.basicConfig(level=logging.WARNING)
        parent = os.getpid()

        def dies_while_it_answers():
            if os.getpid() != parent:
                send = connection.Connection._send

                def cut(self, buf, write=os.write):  # the answer's first 100 kB, then killed
                    if len(buf) > 1_000_000:
                        write(self._handle, bytes(buf[:100_000]))
                        os.kill(os.getpid(), signal.SIGKILL)
                    return send(self, buf, write)

                connection.Connection._send = cut  # in the child only
            return b"x" * 10_000_000

        values = side_by_side([lambda: 1, dies_while_it_answers], what="cut")
        print("done", values[0], len(values[1]))
        """,
        tmp_path,
        timeout=60,  # a hang fails here
    )
    assert result.returncode == 0, result.stderr
    assert "done 1 10000000" in result.stdout
    assert "cut: the process of job 2 ended without an answer" in result.stderr


@needs_two
def test_an_error_here_ends_the_children_at_once():
    def slow() -> None:
        time.sleep(60)

    t0 = time.perf_counter()
    with pytest.raises(ValueError, match="the child's own message"):
        side_by_side([_fail, slow], what="ending")
    assert time.perf_counter() - t0 < 20  # not the child's 60 s
    assert not multiprocessing.active_children()


@needs_two
def test_short_memory_runs_the_jobs_here(monkeypatch, caplog):
    monkeypatch.setattr(_processes, "available_memory", lambda: 1_000_000)
    with caplog.at_level(logging.DEBUG, logger="o3d_ofp"):
        pids = side_by_side([os.getpid, os.getpid], what="pids", memory_each=900_000)
    assert pids == [os.getpid()] * 2
    assert "1 at once" in caplog.text


@needs_two
def test_eigenbases_side_by_side_equal_those_one_after_the_other(monkeypatch, caplog, blob_mesh):
    V, F = blob_mesh  # above the side-by-side threshold
    assert V.shape[0] >= eigenbases_module.SIDE_BY_SIDE_VERTICES
    V2 = V * 2.0 + 1.0
    shapes = [(V, F, 12), (V2, F, 9)]
    with caplog.at_level(logging.DEBUG, logger="o3d_ofp"):
        together = eigenbases_module.eigenbases(shapes)
    assert "eigenbases: 2 at once (1 in forked processes)" in caplog.text
    monkeypatch.setenv(ENVIRONMENT, "1")
    apart = eigenbases_module.eigenbases(shapes)
    for a, b in zip(together, apart, strict=True):
        assert a.k == b.k
        np.testing.assert_array_equal(a.evals, b.evals)  # the same computation, bit for bit
        np.testing.assert_array_equal(a.evecs, b.evecs)


@needs_two
def test_an_error_here_while_a_child_logs_fast_ends_at_once(tmp_path):
    """A child ended while it wrote a record must not block this process (no lock taken here)."""
    result = _run_script(
        """
        import logging, time
        from o3d_ofp.core._processes import side_by_side

        logger = logging.getLogger("o3d_ofp.chatty")
        logger.setLevel(logging.DEBUG)
        seen = []

        class Keep(logging.Handler):
            def emit(self, record):
                seen.append(record.getMessage())

        logger.addHandler(Keep())

        def chatty():
            while True:
                logger.debug("a record from the child")

        def fail_soon():
            time.sleep(0.3)
            raise ValueError("stop here")

        for _ in range(3):
            try:
                side_by_side([fail_soon, chatty], what="chatty")
            except ValueError as exc:
                print(exc)
        print("records from the child:", "a record from the child" in seen)
        """,
        tmp_path,
        timeout=60,  # a hang fails here
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.count("stop here") == 3
    assert "records from the child: True" in result.stdout


@needs_two
def test_a_process_that_cannot_start_leaves_the_job_here(monkeypatch, caplog):
    def refuse(self) -> None:
        raise BlockingIOError(11, "Resource temporarily unavailable")

    monkeypatch.setattr(multiprocessing.context.ForkProcess, "start", refuse)
    with caplog.at_level(logging.WARNING, logger="o3d_ofp"):
        assert side_by_side([os.getpid, os.getpid], what="pids") == [os.getpid()] * 2
    assert "a side process could not start" in caplog.text


def _run_script(code: str, tmp_path, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run ``code`` in a new interpreter that imports the o3d_ofp under test (not another copy)."""
    script = tmp_path / "script.py"
    script.write_text(textwrap.dedent(code))
    root = str(Path(_processes.__file__).resolve().parents[2])  # the directory of o3d_ofp
    path = os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))
    return subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=timeout,
        cwd=tmp_path, env={**os.environ, "PYTHONPATH": path},
    )  # fmt: skip


def _gone(pid: int, seconds: float) -> bool:
    import psutil

    end = time.time() + seconds
    while time.time() < end:
        try:
            if psutil.Process(pid).status() == psutil.STATUS_ZOMBIE:
                return True
        except psutil.NoSuchProcess:
            return True
        time.sleep(0.1)
    return False


@needs_two
def test_a_child_dies_with_its_parent(tmp_path):
    """A parent killed without its clean-up (SIGKILL, a batch scheduler) leaves no child."""
    result = _run_script(
        """
        import os, time
        from o3d_ofp.core._processes import side_by_side

        def child():
            with open("child.tmp", "w") as f:  # renamed when written: the parent, which
                f.write(str(os.getpid()))  # waits for the name, never reads it empty
            os.replace("child.tmp", "child.pid")
            time.sleep(60)
            return b"x" * 10_000_000  # more than a pipe holds

        def parent():
            while not os.path.exists("child.pid"):
                time.sleep(0.05)
            os._exit(0)  # no finally, no terminate: as if killed

        side_by_side([parent, child], what="orphan")
        """,
        tmp_path,
    )
    assert result.returncode == 0, result.stderr
    pid = int((tmp_path / "child.pid").read_text())
    assert _gone(pid, 10), f"child {pid} outlived its parent"


@needs_two
def test_a_fork_while_another_thread_holds_the_blas_lock_does_not_hang(tmp_path):
    """o3d_ofp.core._threads' lock held by another thread at the fork (a concurrent call)."""
    result = _run_script(
        """
        import threading, time
        from o3d_ofp.core import _threads
        from o3d_ofp.core.shapes import blob
        from o3d_ofp.workflows.eigenbases import eigenbases

        V, F = blob(4)
        held = threading.Event()

        def hold():
            with _threads._LOCK:
                held.set()
                time.sleep(1.0)

        threading.Thread(target=hold, daemon=True).start()  # a daemon: the fork goes ahead
        held.wait()
        out = eigenbases([(V, F, 8), (V * 2.0, F, 8)])
        print("done", [e.k for e in out])
        """,
        tmp_path,
        timeout=90,
    )
    assert result.returncode == 0, result.stderr
    assert "done [8, 8]" in result.stdout


@needs_two
def test_no_fork_while_other_threads_run_or_from_another_thread():
    """A fork can catch another thread inside OpenBLAS, whose fork handler then hangs."""
    import threading

    stop = threading.Event()
    busy = threading.Thread(target=stop.wait)  # any non-daemon thread of the caller
    busy.start()
    try:
        assert processes_available() == 1
        assert side_by_side([os.getpid, os.getpid], what="pids") == [os.getpid()] * 2
    finally:
        stop.set()
        busy.join()
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as pool:  # called from a thread: one process
        assert pool.submit(processes_available).result() == 1
    assert processes_available() > 1  # and from the main thread alone again


def test_a_setting_below_one_is_said(monkeypatch, caplog):
    monkeypatch.setenv(ENVIRONMENT, "0")
    with caplog.at_level(logging.WARNING, logger="o3d_ofp"):
        assert processes_available() == 1
    assert f"{ENVIRONMENT}=0: taken as 1" in caplog.text
