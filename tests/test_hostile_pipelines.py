"""A pipeline from someone else: every size and number in it is checked before it is spent.

Each case builds the hostile pipeline (or a log carrying it) and runs the command line: one
``error:`` line naming the file and the key, exit code 2, no traceback, and nothing written.
A multiverse is counted from its axes before any universe is built, and each level of an axis
is held to the limits of a single study; a number outside the 64-bit integers and floats, a
name too long for a file name, too few subjects to analyse and a learning phase too long for
the best response's exact search are refused where the file is read.
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
from cirl_study.study.spec import MAX_NAME_LENGTH

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


# --- numbers past what the code represents ------------------------------------------------------

HUGE = "1" + "0" * 400


@pytest.mark.parametrize(
    ("old", "new", "says"),
    [
        ("seed = 7", f"seed = {HUGE}", "seed holds an integer of 401 digits, beyond the 64-bit"),
        ("seed = 7", f"seed = {'9' * 5000}", "holds an integer of more than 4300 digits"),
        ("width = 5", f"width = {HUGE}", "game.width holds an integer of 401 digits"),
        ("width = 5", "width = 9223372036854775808", "game.width holds an integer of 19 digits"),
        ("sigma = 0.75", f"sigma = {HUGE}", "game.sigma holds an integer of 401"),
        ("sigma = 0.75", "sigma = 1e400", "game.sigma holds 1e400, which overflows a 64-bit"),
        ("sigma = 0.75", "sigma = -1e400", "game.sigma holds -1e400, which overflows"),
        ("sigma = 0.75", "sigma = 1e-400", "game.sigma holds 1e-400, which underflows"),
        ("learning_steps = 4", f"learning_steps = {HUGE}", "game.learning_steps holds an"),
        ("feature_levels = [3, 10]", f"feature_levels = [3, {HUGE}]", "game.feature_levels hold"),
        ("etas = [0.1, 1.0, 10.0]", "etas = [0.1, 1e999]", "eta_cv.etas holds 1e999"),
        ("[main]\nsubjects = 4", f"[main]\nsubjects = {HUGE}", "main.subjects holds an integer"),
        ("rationality = 1.0\nhumans", f"rationality = {HUGE}\nhumans", "main.rationality holds"),
        ("rationalities = [0.1, 1.0, 10.0]", f"rationalities = [{HUGE}]", "rationalities holds"),
    ],
)
def test_a_number_past_64_bits_is_one_line_naming_its_key(
    tmp_path: Path, old: str, new: str, says: str
) -> None:
    refused_by_run(tmp_path, replaced(SMOKE, old, new), says)


@pytest.mark.parametrize(
    ("level", "says"),
    [
        (f"sigma = [1.0, {HUGE}]", "sigma holds an integer of 401 digits"),
        ("rationality = [1e400]", "rationality holds 1e400, which overflows"),
        (f"steps = [{HUGE}]", "steps holds an integer of 401 digits"),
    ],
)
def test_a_number_past_64_bits_in_a_level_is_one_line(
    tmp_path: Path, level: str, says: str
) -> None:
    refused_by_run(
        tmp_path, MULTIVERSE + f"[multiverse.alone]\n{level}\n", "multiverse.alone." + says
    )


def test_the_largest_64_bit_numbers_are_read_as_any_other(tmp_path: Path) -> None:
    seed = replaced(SMOKE, "seed = 7", "seed = 9223372036854775807")
    assert parse_pipeline(seed, Path("x.toml")).seed == 2**63 - 1
    refused_by_run(tmp_path, replaced(SMOKE, "sigma = 0.75", "sigma = 1.7e308"), "game.sigma must")
    refused_by_run(tmp_path, replaced(SMOKE, "width = 5", f"width = {2**63 - 1}"), "one batch of")


# --- names, subjects ----------------------------------------------------------------------------


def test_a_name_too_long_for_a_file_name_is_refused_before_a_directory_is_made(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 300-character name would name ``data/runs/<name>`` (refused by the OS as too long),
    and a report's staging directory, 18 characters longer."""
    monkeypatch.chdir(tmp_path)
    pipeline = tmp_path / "long.toml"
    pipeline.write_text(replaced(SMOKE, 'name = "smoke"', f'name = "{"a" * 300}"'))
    for _ in range(2):  # the second run was where the OS's error came, as a traceback
        one_line(
            invoke("run", pipeline),
            f"long.toml: name must be at most {MAX_NAME_LENGTH} characters (it names a "
            "directory, and a file name holds 255 bytes with the suffixes added to it), got 300 "
            "characters",
        )
        assert not (tmp_path / "data").exists()
    longest = replaced(SMOKE, 'name = "smoke"', f'name = "{"a" * MAX_NAME_LENGTH}"')
    assert len(parse_pipeline(longest, Path("x.toml")).name) == MAX_NAME_LENGTH
    staged = f".{'a' * MAX_NAME_LENGTH}.tmp-abcdefgh-old"
    assert len(staged) == 255
    (tmp_path / staged).mkdir()  # the longest name the code makes of it fits a file name
    refused_by_run(
        tmp_path,
        replaced(MULTIVERSE, 'name = "smoke"', f'name = "{"a" * MAX_NAME_LENGTH}"')
        + "[multiverse.alone]\nsteps = [3]\n",
        f"name must be at most {MAX_NAME_LENGTH - 6} characters in a multiverse",
    )


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ("[main]\nsubjects = 4", "[main]\nsubjects = 1", "main.subjects"),
        ("[eta_cv]\nsubjects = 3", "[eta_cv]\nsubjects = 1", "eta_cv.subjects"),
        ("[lambda_sweep]\nsubjects = 4", "[lambda_sweep]\nsubjects = 1", "lambda_sweep.subjects"),
    ],
)
def test_too_few_subjects_to_analyse_are_refused_before_the_first_trial(
    tmp_path: Path, old: str, new: str, key: str
) -> None:
    """One reward draw per feature level leaves the analysis no spread to test against (the
    ANOVA's error terms, a mean's standard error): refused by ``run``, not by ``analyze``
    after the run."""
    refused_by_run(
        tmp_path,
        replaced(SMOKE, old, new),
        f"{key} must be an integer of at least 2 (the analysis needs the spread of two reward "
        "draws per feature level), got 1",
    )


def test_two_subjects_are_enough_to_analyse(tmp_path: Path) -> None:
    text = replaced(SMOKE, "[main]\nsubjects = 4", "[main]\nsubjects = 2")
    text = replaced(text, "[eta_cv]\nsubjects = 3", "[eta_cv]\nsubjects = 2")
    text = replaced(text, "[lambda_sweep]\nsubjects = 4", "[lambda_sweep]\nsubjects = 2")
    pipeline = tmp_path / "two.toml"
    pipeline.write_text(text)
    run, report = tmp_path / "run", tmp_path / "report"
    played = invoke("run", pipeline, "--out", run, "--workers", "1")
    assert played.exit_code == 0, played.output
    analysed = invoke("analyze", run, "--out", report)
    assert analysed.exit_code == 0, analysed.output
    assert (report / "results.json").is_file()
