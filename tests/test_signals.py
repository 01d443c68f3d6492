"""No wait without end: a run whose worker dies, or that a signal stops, ends at once in one line.

Each test starts ``python -m cirl_study`` as a user would, waits for an observable state (a
first log file, a worker process), then kills a worker or sends a signal, and checks: a
non-zero exit in bounded time, one line on stderr (beside the progress lines) and no
traceback, the lock released, nothing in the run directory but complete log files, and a
resumed run that plays exactly the missing trials into the records of an uninterrupted run.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from test_runner_engines import trial_payloads

from cirl_study.escape import shell
from cirl_study.interrupts import PARENT_POLL_SECONDS
from cirl_study.logs.lock import LOCK_NAME, writer_pid
from cirl_study.study.engines import LocalEngine
from cirl_study.study.pipeline_file import load_pipeline
from cirl_study.study.runner import run_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"

pytestmark = pytest.mark.skipif(
    not hasattr(signal, "SIGHUP") or not Path("/proc/self/task").is_dir(),
    reason="needs POSIX signals and /proc to find a process's children",
)

SECONDS = 60
"""Bound on every wait of these tests: a command still running then is hung."""

PROGRESS = re.compile(r"(preparing |numerical kernels ready in |trials: )")
"""The start of the progress lines a run writes on stderr outside a terminal."""


def _pipeline(directory: Path) -> Path:
    """The smoke pipeline with more reward draws (1256 trials), so that a run goes on for a
    second or so after its first log file."""
    text = SMOKE.read_text()
    for block, subjects in (("eta_cv", 6), ("main", 40), ("lambda_sweep", 40)):
        old = f"[{block}]\nsubjects = "
        start = text.index(old) + len(old)
        text = text[:start] + str(subjects) + text[text.index("\n", start) :]
    path = directory / "signals.toml"
    path.write_text(text)
    return path


_AT_DEFAULT = {signal.SIGINT: signal.default_int_handler, signal.SIGHUP: signal.SIG_DFL}
"""The signals a terminal's foreground job starts with at their defaults, and those defaults."""


@pytest.fixture(scope="module", autouse=True)
def _signals_reach_the_commands() -> Iterator[None]:
    """The commands start as a terminal's foreground job does, Ctrl-C and hang-up at their
    defaults, also when the suite runs with them ignored (``pytest &`` in a script ignores
    SIGINT, ``nohup`` SIGHUP), which a command would inherit and, rightly, keep."""
    ignored = [number for number in _AT_DEFAULT if signal.getsignal(number) == signal.SIG_IGN]
    for number in ignored:
        signal.signal(number, _AT_DEFAULT[number])
    try:
        yield
    finally:
        for number in ignored:
            signal.signal(number, signal.SIG_IGN)


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _pipeline(tmp_path_factory.mktemp("pipeline"))


@pytest.fixture(scope="module")
def reference(pipeline: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An uninterrupted run of :func:`pipeline`."""
    out = tmp_path_factory.mktemp("reference") / "run"
    run_pipeline(load_pipeline(pipeline), out, LocalEngine(2))
    return out


def command(*arguments: str) -> list[str]:
    return [sys.executable, "-m", "cirl_study", *arguments]


def popen(argv: list[str], **options: Any) -> subprocess.Popen[str]:
    """``argv`` in a process group of its own, as a terminal's foreground job is, its output
    read here (unless ``options`` say otherwise)."""
    defaults = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True}
    return subprocess.Popen(argv, **{**defaults, **options}, start_new_session=True)


def start(*arguments: str) -> subprocess.Popen[str]:
    """``python -m cirl_study`` with ``arguments`` (:func:`popen`)."""
    return popen(command(*arguments))


def wait_for(condition: Callable[[], object], process: subprocess.Popen[str]) -> None:
    """Poll until ``condition()`` holds, the process still running."""
    deadline = time.monotonic() + SECONDS
    while not condition():
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "the state awaited never came"
        time.sleep(0.002)


def children(pid: int) -> list[int]:
    """The process ids of ``pid``'s children."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            found += [int(child) for child in (task / "children").read_text().split()]
    return found


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def running(pid: int) -> bool:
    """Whether ``pid`` is a process that has not ended (a zombie, not yet reaped, has)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@contextlib.contextmanager
def group_ended(process: subprocess.Popen[str]) -> Iterator[None]:
    """Kill what is left of ``process``'s group after the block, whatever happened."""
    try:
        yield
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=SECONDS)


def ended(process: subprocess.Popen[str]) -> tuple[int, str]:
    """The exit code and the one line the command wrote on stderr beside its progress."""
    _, stderr = process.communicate(timeout=SECONDS)
    assert "Traceback" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if not PROGRESS.match(line)]
    assert len(lines) == 1, stderr
    return process.returncode, lines[0]


def kept(line: str, pipeline: Path, out: Path) -> int:
    """The number of trials ``line`` says the run kept; it names the command that resumes."""
    resume = f"resume with `cirl-study run {shell(pipeline)} --out {shell(out)}`"
    found = re.search(r": (\d+) trials kept; (.*)$", line)
    assert found is not None and found[2] == resume, line
    return int(found[1])


def check_resumes(out: Path, pipeline: Path, reference: Path, kept: int) -> None:
    """The lock is free and the directory holds complete logs alone, ``kept`` trials; a
    resumed run plays exactly the others, into the records of the uninterrupted run."""
    assert writer_pid(out) is None
    assert {path.name for path in out.iterdir()} - {LOCK_NAME} == {
        path.name for path in out.glob("*.mcap")
    }
    logged = trial_payloads(out)
    total = len(trial_payloads(reference))
    assert len(logged) == kept and 0 < kept < total, "the run was not stopped mid-run"
    done = subprocess.run(
        command("run", str(pipeline), "--out", str(out), "--workers", "2"),
        capture_output=True,
        text=True,
        timeout=SECONDS,
    )
    assert done.returncode == 0, done.stderr
    assert f"{total - kept} played now, {kept} were already logged" in done.stdout
    resumed = trial_payloads(out)
    assert {trial: resumed[trial] for trial in logged} == logged
    assert resumed == trial_payloads(reference)
    checked = subprocess.run(
        command("validate", str(out)), capture_output=True, text=True, timeout=SECONDS
    )
    assert checked.returncode == 0 and "OK" in checked.stdout, checked.stdout + checked.stderr


def kill_a_worker(process: subprocess.Popen[str]) -> None:
    os.kill(children(process.pid)[0], signal.SIGKILL)


def terminate(process: subprocess.Popen[str]) -> None:
    os.kill(process.pid, signal.SIGTERM)


def hang_up(process: subprocess.Popen[str]) -> None:
    os.killpg(process.pid, signal.SIGHUP)  # a terminal closed: its whole foreground group


def ctrl_c_twice(process: subprocess.Popen[str]) -> None:
    os.killpg(process.pid, signal.SIGINT)
    os.killpg(process.pid, signal.SIGINT)


@pytest.mark.parametrize(
    ("stop", "exit_code", "cause"),
    [
        (kill_a_worker, 1, "error: worker died (signal 9)"),
        (terminate, 128 + signal.SIGTERM, "interrupted (SIGTERM)"),
        (hang_up, 128 + signal.SIGHUP, "interrupted (SIGHUP)"),
        (ctrl_c_twice, 128 + signal.SIGINT, "interrupted (SIGINT)"),
    ],
    ids=["kill-9-a-worker", "sigterm", "sighup", "ctrl-c-twice"],
)
def test_a_stopped_run_says_so_in_one_line_and_resumes_exactly(
    stop: Callable[[subprocess.Popen[str]], None],
    exit_code: int,
    cause: str,
    pipeline: Path,
    reference: Path,
    tmp_path: Path,
) -> None:
    out = tmp_path / "run"
    process = start("run", str(pipeline), "--out", str(out), "--workers", "2")
    with group_ended(process):
        wait_for(lambda: list(out.glob("*.mcap")) and len(children(process.pid)) == 2, process)
        workers = children(process.pid)
        began = time.monotonic()
        stop(process)
        code, line = ended(process)
        assert time.monotonic() - began < 10
    assert code == exit_code, line
    assert line.startswith(cause), line
    if line == cause:  # the second Ctrl-C came while the first was still stopping the run
        count = len(trial_payloads(out))
    else:
        count = kept(line.removeprefix(cause), pipeline, out)
    deadline = time.monotonic() + SECONDS
    while any(alive(worker) for worker in workers):
        assert time.monotonic() < deadline, "workers outlived the run"
        time.sleep(0.01)
    check_resumes(out, pipeline, reference, count)


@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGTERM], ids=["sighup", "sigterm"])
def test_a_signal_to_a_run_on_a_local_dask_cluster_is_one_line(
    signum: signal.Signals, pipeline: Path, reference: Path, tmp_path: Path
) -> None:
    """The signal reaches the cluster's processes too (a terminal's hang-up, ``kill`` of the
    group): only the main process reports it."""
    pytest.importorskip("distributed")
    out = tmp_path / "run"
    process = start("run", str(pipeline), "--out", str(out), "--engine", "dask", "--workers", "2")
    with group_ended(process):
        wait_for(lambda: list(out.glob("*.mcap")), process)
        os.killpg(process.pid, signum)
        code, line = ended(process)
    assert code == 128 + signum
    cause = f"interrupted ({signum.name})"
    assert line.startswith(cause), line
    check_resumes(out, pipeline, reference, kept(line.removeprefix(cause), pipeline, out))


_STOPPING_SLOWLY = """
import sys, time
from cirl_study import interrupts
interrupts.install()
try:
    print("started", flush=True)
    time.sleep(60)
except KeyboardInterrupt:
    print("stopping", flush=True)
    time.sleep(60)
"""


def test_a_second_ctrl_c_exits_at_once() -> None:
    """While the first Ctrl-C is still being handled (here: for a minute), a second one
    ends the process at once, in one line, with the first's exit code."""
    process = popen([sys.executable, "-c", _STOPPING_SLOWLY])
    with group_ended(process):
        assert process.stdout is not None and process.stdout.readline() == "started\n"
        os.killpg(process.pid, signal.SIGINT)
        assert process.stdout.readline() == "stopping\n"
        began = time.monotonic()
        os.killpg(process.pid, signal.SIGINT)
        _, stderr = process.communicate(timeout=SECONDS)
        assert time.monotonic() - began < 5
    assert process.returncode == 128 + signal.SIGINT
    assert stderr == "interrupted (SIGINT)\n"


@contextlib.contextmanager
def analyze_reading(reference: Path, run: Path) -> Iterator[subprocess.Popen[str]]:
    """``cirl-study analyze`` of ``run``, a copy of the reference run, once its workers read
    the logs; what is left of it is killed after the block."""
    shutil.copytree(reference, run)
    process = start("analyze", str(run))
    with group_ended(process):
        wait_for(lambda: children(process.pid), process)
        yield process


def test_ctrl_c_during_analyze_is_one_line(reference: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    with analyze_reading(reference, run) as process:
        os.killpg(process.pid, signal.SIGINT)
        code, line = ended(process)
    assert (code, line) == (128 + signal.SIGINT, "interrupted (SIGINT)")
    assert sorted(path.name for path in run.iterdir()) == sorted(
        path.name for path in reference.iterdir()
    )


def test_the_workers_of_a_killed_analyze_end_with_it(reference: Path, tmp_path: Path) -> None:
    with analyze_reading(reference, tmp_path / "run") as process:
        workers = children(process.pid)
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=SECONDS)
        gone = time.monotonic() + 10 * PARENT_POLL_SECONDS + 5
        while any(map(running, workers)) and time.monotonic() < gone:
            time.sleep(0.05)
        assert not any(map(running, workers))


_SCHEDULER = """
import sys
from distributed import LocalCluster
with LocalCluster(
    n_workers=0, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
) as cluster:
    print(cluster.scheduler_address, flush=True)
    sys.stdin.read()
"""


@pytest.fixture
def cluster() -> Iterator[tuple[str, subprocess.Popen[str]]]:
    """A Dask scheduler without workers, for the test's duration: its address, its process."""
    pytest.importorskip("distributed")
    process = popen([sys.executable, "-c", _SCHEDULER], stdin=subprocess.PIPE, stderr=None)
    with group_ended(process):
        assert process.stdout is not None
        yield process.stdout.readline().strip(), process


def start_on_dask(pipeline: Path, out: Path, scheduler: str) -> subprocess.Popen[str]:
    return start(
        *("run", str(pipeline), "--out", str(out), "--engine", "dask"),
        *("--scheduler", scheduler, "--no-workers-timeout", "1"),
    )


@contextlib.contextmanager
def dask_worker(scheduler: str) -> Iterator[subprocess.Popen[str]]:
    """A worker of ``scheduler`` (without a nanny, which would start it again when killed),
    once the scheduler has it."""
    from distributed import Client

    worker = popen(
        [sys.executable, "-m", "distributed.cli.dask_worker", scheduler, "--no-nanny"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    with group_ended(worker):
        with Client(scheduler, timeout=SECONDS) as client:
            client.wait_for_workers(1, timeout=SECONDS)
        yield worker


def test_a_dask_cluster_without_workers_stops_the_run(
    cluster: tuple[str, subprocess.Popen[str]], pipeline: Path, tmp_path: Path
) -> None:
    scheduler, _ = cluster
    out = tmp_path / "new" / "run"
    process = start_on_dask(pipeline, out, scheduler)
    with group_ended(process):
        code, line = ended(process)
    assert code == 1
    assert line.startswith(f"error: the Dask scheduler at {scheduler} has had no workers for 1 s")
    assert kept(line, pipeline, out) == 0
    assert list(tmp_path.iterdir()) == []  # nothing was logged, so nothing is left


@pytest.mark.parametrize("lost", ["worker", "scheduler"])
def test_a_dask_run_that_loses_its_workers_stops_and_resumes_exactly(
    lost: str,
    cluster: tuple[str, subprocess.Popen[str]],
    pipeline: Path,
    reference: Path,
    tmp_path: Path,
) -> None:
    scheduler, scheduler_process = cluster
    out = tmp_path / "run"
    with dask_worker(scheduler) as worker:
        process = start_on_dask(pipeline, out, scheduler)
        with group_ended(process):
            wait_for(lambda: list(out.glob("*.mcap")), process)
            (worker if lost == "worker" else scheduler_process).kill()
            code, line = ended(process)
    assert code == 1
    no_workers = f"error: the Dask scheduler at {scheduler} has had no workers for 1 s"
    lost_scheduler = f"error: lost the connection to the Dask scheduler at {scheduler}"
    # A scheduler too busy to answer while its worker dies is lost to the client first.
    causes = [no_workers, lost_scheduler] if lost == "worker" else [lost_scheduler]
    cause = next((c for c in causes if line.startswith(c)), None)
    assert cause is not None, line
    check_resumes(out, pipeline, reference, kept(line.removeprefix(cause), pipeline, out))


_INTERRUPTED_IN_A_FINALIZER = """
import time
from cirl_study import interrupts
interrupts.install()

class Slow:
    def __del__(self):
        print("finalizing", flush=True)
        time.sleep(60)

try:
    Slow()
    time.sleep(60)
except KeyboardInterrupt:
    print("stopped", flush=True)
"""


def test_a_signal_where_python_ignores_exceptions_is_not_lost() -> None:
    """Ctrl-C in a finalizer (or an at-fork hook, where ``analyze`` forks its workers), where
    Python would print the exception and go on, stops the command all the same, silently."""
    process = popen([sys.executable, "-c", _INTERRUPTED_IN_A_FINALIZER])
    with group_ended(process):
        assert process.stdout is not None and process.stdout.readline() == "finalizing\n"
        os.killpg(process.pid, signal.SIGINT)
        stdout, stderr = process.communicate(timeout=SECONDS)
    assert (stdout, stderr, process.returncode) == ("stopped\n", "", 0)


_HELD_BACK = """
import threading, time
from cirl_study import interrupts
interrupts.install()
threading.Thread(target=time.sleep, args=(60,), daemon=True).start()
try:
    with interrupts.deferred():
        print("holding", flush=True)
        time.sleep(1)
        print("held", flush=True)
except KeyboardInterrupt as interrupt:
    print(f"then {interrupt.line()}", flush=True)
"""


def test_a_deferred_step_ends_before_the_signal_acts_whichever_thread_it_reached() -> None:
    """A batch's log file and its count are one step for a signal, also in a process with
    threads (a Dask client's, a progress bar's), where the signal may reach another thread."""
    process = popen([sys.executable, "-c", _HELD_BACK])
    with group_ended(process):
        assert process.stdout is not None and process.stdout.readline() == "holding\n"
        os.kill(process.pid, signal.SIGTERM)
        stdout, stderr = process.communicate(timeout=SECONDS)
    assert (stdout, stderr) == ("held\nthen interrupted (SIGTERM)\n", "")


_STUCK_WORKERS = """
import ctypes, os, sys
from pathlib import Path

marks = Path(sys.argv[1])
MAIN = os.getpid()


def stuck(*arguments):
    '''In a worker: note its pid, then a minute in libc's sleep holding the GIL, as a compiled
    kernel does (no Python thread of the worker runs meanwhile).'''
    if os.getpid() != MAIN:
        (marks / str(os.getpid())).touch()
        ctypes.PyDLL(None).sleep(60)
    return arguments


if sys.argv[2] == "pool":
    import cirl_study.workers as workers

    workers.cores = lambda: 2
    list(workers.map_in_workers(stuck, [1, 2]))
else:
    from cirl_study.core.players import HUMANS, Human, register_human
    from cirl_study.study.engines import LocalEngine
    from cirl_study.study.pipeline_file import load_pipeline
    from cirl_study.study.runner import run_pipeline

    def demonstrate(game, theta, eta, seeds):
        stuck()
        return HUMANS["expert"].demonstrate(game, theta, eta, seeds)

    register_human("stuck", Human(demonstrate, takes_eta=False))
    run_pipeline(load_pipeline(Path(sys.argv[3])), Path(sys.argv[4]), LocalEngine(2))
"""


@pytest.mark.parametrize("workers", ["pool", "run"])
def test_workers_end_with_a_killed_parent_whatever_they_compute(
    tmp_path: Path, workers: str
) -> None:
    """SIGKILL to the parent while every worker is inside a call that holds the GIL (where no
    thread of the worker can poll for its parent): the kernel ends each worker at once, on
    its own (``prctl(PR_SET_PDEATHSIG)``), whether the workers are a pool's
    (:func:`cirl_study.workers.map_in_workers`, as ``analyze`` and ``aside`` fork them) or a
    run's (:class:`cirl_study.study.engines.LocalEngine`)."""
    marks = tmp_path / "workers"
    marks.mkdir()
    pipeline = tmp_path / "stuck.toml"
    text = SMOKE.read_text().replace('humans = ["expert", "best_response"]', 'humans = ["stuck"]')
    pipeline.write_text(text)
    arguments = [str(marks), workers, str(pipeline), str(tmp_path / "run")]
    process = popen([sys.executable, "-c", _STUCK_WORKERS, *arguments], stdout=None)
    with group_ended(process):
        wait_for(lambda: len(list(marks.iterdir())) == 2, process)
        stuck = [int(mark.name) for mark in marks.iterdir()]
        assert all(map(running, stuck))
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=SECONDS)
        gone = time.monotonic() + 5
        while any(map(running, stuck)) and time.monotonic() < gone:
            time.sleep(0.05)
        assert not any(map(running, stuck)), "a worker outlived its killed parent"
