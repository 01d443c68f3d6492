"""A pipeline from someone else: every size in it is checked before it is spent.

Each case builds the hostile pipeline (or a log carrying it) and runs the command line: one
``error:`` line naming the file and the key, exit code 2, no traceback, and nothing written.
A multiverse is counted from its axes before any universe is built, and each level of an axis
is held to the limits of a single study; a learning phase too long for the best response's
exact search is refused where the file is read.
"""

from __future__ import annotations

import contextlib
import hashlib
import shutil
import signal
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.logs.contents import read_file_contents
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.writer import TrialLogWriter
from cirl_study.study.limits import MAX_SEARCH_STEPS
from cirl_study.study.pipeline_file import parse_pipeline

ROOT = Path(__file__).resolve().parent.parent
SMOKE = (ROOT / "pipelines" / "smoke.toml").read_text()
PAPER = (ROOT / "pipelines" / "paper.toml").read_text()
SWEEP = SMOKE[SMOKE.index("[lambda_sweep]") :]
MULTIVERSE = SMOKE.replace(SWEEP, "")
"""The smoke pipeline without its sweep: a multiverse once ``[multiverse...]`` is added."""


@contextlib.contextmanager
def within(seconds: int) -> Iterator[None]:
    """Fail the block if it takes longer than ``seconds`` (a size believed, being spent)."""

    def stop(signum: int, frame: object) -> None:
        raise TimeoutError(f"still working after {seconds} s")

    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def invoke(*args: object):
    return CliRunner().invoke(app, [str(arg) for arg in args])


def one_line(result, *fragments: str) -> str:
    """Exit code 2 and a single ``error:`` line holding every fragment, no traceback."""
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("error: "), result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    for fragment in fragments:
        assert fragment in result.stderr, result.stderr
    return result.stderr


def refused_by_run(tmp_path: Path, text: str, *fragments: str) -> str:
    """``run`` of the pipeline ``text`` is one line holding ``fragments``, and writes nothing."""
    pipeline = tmp_path / "hostile.toml"
    pipeline.write_text(text)
    out = tmp_path / "out"
    with within(30):
        line = one_line(invoke("run", pipeline, "--out", out), "hostile.toml: ", *fragments)
    assert not out.exists()
    return line


def replaced(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def levels(count: int, first: float, step: float) -> str:
    return "[" + ", ".join(repr(round(first + i * step, 6)) for i in range(count)) + "]"


# --- sizes believed too late --------------------------------------------------------------------

CROSSED = (
    MULTIVERSE
    + "[multiverse.cross]\n"
    + f"sigma = {levels(300, 0.1, 0.01)}\n"
    + f"rationality = {levels(300, 0.001, 0.001)}\n"
    + f"steps = {list(range(1, MAX_SEARCH_STEPS + 1))}\n"
)
"""A 5 KB multiverse of 300 x 300 x 14 universes: 1,260,001 universes of 34 trials."""


def test_a_multiverse_is_counted_from_its_axes_before_a_universe_is_built(tmp_path: Path) -> None:
    assert len(CROSSED) < 6000
    refused_by_run(
        tmp_path,
        CROSSED,
        "multiverse may plan 1260001 universes of 34 trials each, 42840034 trials, more than "
        "the 2000000 one run may hold",
    )


def test_logs_carrying_such_a_multiverse_are_refused_as_fast(
    tmp_path: Path, smoke_run: Path
) -> None:
    """The smoke run's log files (tens of KB each), their provenance carrying the multiverse
    above: every reader refuses them as it reads the pipeline, before a universe is built."""
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run)
    run_id = f"smoke-{hashlib.sha256(CROSSED.encode()).hexdigest()[:12]}"
    identity = RunIdentity(run_id, "smoke", "crossed.toml", CROSSED)
    for log in run.glob("*.mcap"):
        contents = read_file_contents(log)
        provenance = {**contents.provenance, **identity.provenance()}
        log.unlink()
        with stand_in_identity(), TrialLogWriter(log, provenance) as writer:
            for record in contents.records:
                writer.write(msgspec.structs.replace(record, run_id=run_id))
        assert log.stat().st_size < 64_000
    with within(30):
        result = invoke("validate", run)
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    assert "multiverse may plan 1260001 universes" in result.output, result.output
    with within(30):
        one_line(invoke("analyze", run, "--out", tmp_path / "report"), "multiverse may plan")
    assert not (tmp_path / "report").exists()


@contextlib.contextmanager
def stand_in_identity() -> Iterator[None]:
    """Let the writer log a provenance whose pipeline it would refuse (as a log from someone
    else may carry)."""
    import cirl_study.logs.writer as writer

    class Believed:
        def __init__(self, run_id: str) -> None:
            self.run_id = run_id

        @staticmethod
        def of(provenance):
            return Believed(provenance["run_id"])

    saved = writer.RunIdentity
    writer.RunIdentity = Believed
    try:
        yield
    finally:
        writer.RunIdentity = saved


@pytest.mark.parametrize(
    ("table", "level"),
    [("multiverse.alone", "steps = [1000000000]"), ("multiverse.cross", "steps = [4, 1000000000]")],
)
def test_a_level_is_held_to_the_limits_of_a_single_study(
    tmp_path: Path, table: str, level: str
) -> None:
    """``steps = 10^9`` as a level asks what ``game.learning_steps = 10^9`` would: refused."""
    single = replaced(SMOKE, "learning_steps = 4", "learning_steps = 1000000000")
    single = replaced(single, "deployment_steps = 4", "deployment_steps = 1000000000")
    refused_by_run(tmp_path, single, "one batch of trials would need about 5.36e+06 GiB")
    refused_by_run(
        tmp_path,
        MULTIVERSE + f"[{table}]\n{level}\n",
        f"{table}.steps level 1000000000: one batch of trials would need about 5.36e+06 GiB, "
        "more than the 4 GiB budget",
    )


def test_a_listed_universe_is_held_to_the_same_limits(tmp_path: Path) -> None:
    refused_by_run(
        tmp_path,
        MULTIVERSE + "[[multiverse.universes]]\nsteps = 100000\n",
        "multiverse.universes[0].steps level 100000: one batch of trials would need about",
    )


@pytest.mark.parametrize(
    "universes",
    [
        '[multiverse.alone]\nrobot = ["pragmatic"]',
        '[[multiverse.universes]]\nrobot = "literal_observer"',
    ],
)
def test_a_robot_level_that_needs_a_hypothesis_space_is_refused_before_the_first_trial(
    tmp_path: Path, universes: str
) -> None:
    """A multiverse has no ``[teaching]``: such a universe's first trial would fail mid-run."""
    refused_by_run(
        tmp_path,
        MULTIVERSE + universes + "\n",
        "robot must be ",
        "(a multiverse has no hypothesis space), got ",
    )


def test_the_best_response_is_held_to_the_horizon_its_search_affords(tmp_path: Path) -> None:
    """Its exact search grows about fourfold a step: past :data:`MAX_SEARCH_STEPS` learning
    steps a pipeline where it plays is refused before the first trial; a study without it
    is not."""
    longer = MAX_SEARCH_STEPS + 1
    paper = replaced(PAPER, "learning_steps = 9", f"learning_steps = {longer}")
    problem = f"{longer} learning steps, more than the {MAX_SEARCH_STEPS} where best_response plays"
    refused_by_run(tmp_path, paper, f"hostile.toml: {problem}: her exact path search grows")
    expert = replaced(paper, '"expert", "best_response"', '"expert"')
    assert parse_pipeline(expert, Path("x.toml")).game.learning_steps == longer
    at_most = replaced(PAPER, "learning_steps = 9", f"learning_steps = {MAX_SEARCH_STEPS}")
    assert parse_pipeline(at_most, Path("x.toml")).game.learning_steps == MAX_SEARCH_STEPS
    refused_by_run(
        tmp_path,
        MULTIVERSE + f"[multiverse.alone]\nsteps = [3, {longer}]\n",
        f"multiverse.alone.steps level {longer}: {problem}",
    )
