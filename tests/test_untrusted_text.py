"""Nothing a log says is believed unchecked, and nothing from outside is printed raw.

A run directory may come from someone else. Its provenance is checked against the pipeline
text it carries (validated as a pipeline file is, limits included) and against the run id;
every string from a log or a path is escaped for where it goes (a terminal, a report, a shell
command); and the advice ``validate`` and ``analyze`` give is a command that works: quoted,
naming a file that holds the run's pipeline, or saying that a run is still being written.
Each case builds the hostile input, and asserts the exit code, one line where a command
refuses, and that no raw control character reaches the output.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest
from typer.testing import CliRunner

import cirl_study
from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.escape import TERMINAL_LIMIT, markdown, shell, terminal
from cirl_study.logs.contents import read_file_contents
from cirl_study.logs.format import LOG_SUFFIX, TEMP_SUFFIX, log_files
from cirl_study.logs.lock import LOCK_NAME, writer_lock, writer_pid
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.writer import TrialLogWriter
from cirl_study.record import TrialRecord
from cirl_study.study.pipeline_file import load_pipeline, parse_pipeline, resolve_pipeline
from cirl_study.study.runner import run_identity

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"
SMOKE_RUN_ID = load_pipeline(SMOKE).run_id

HOSTILE_NAME = "smoke](https://evil.example) <img src=x onerror=alert(1)> **OK**"
HOSTILE_FILE = "smoke.toml --out x; touch PWNED; #"


def invoke(*args: object):
    return CliRunner().invoke(app, [str(arg) for arg in args])


def raw_free(text: str) -> None:
    """No character a terminal would obey rather than show: line breaks only end lines."""
    assert all(line.isprintable() for line in text.splitlines()), repr(text[:500])
    assert "\r" not in text and "\x1b" not in text


def one_line(result, code: int, *contains: str) -> str:
    """The exit code, and a single ``error:`` line holding every one of ``contains``."""
    assert result.exit_code == code, result.output
    assert result.stderr.startswith("error: ") and result.stderr.count("\n") == 1, result.stderr
    raw_free(result.stderr)
    for text in contains:
        assert text in result.stderr, (text, result.stderr)
    return result.stderr


def advised_command(text: str) -> list[str]:
    """The command of the ``resume with `...``` advice in ``text``, split as a shell would."""
    start = text.index("resume with `") + len("resume with `")
    return shlex.split(text[start : text.index("`", start)])


def rewrite(
    source: Path,
    target: Path,
    provenance: Callable[[dict[str, str]], dict[str, str]] = lambda p: p,
    record: Callable[[TrialRecord], TrialRecord] = lambda r: r,
) -> Path:
    """Copy the run ``source`` to ``target``, every file written again with its provenance and
    its records changed, past the writer's own checks, as a hand-made file would be."""
    target.mkdir(parents=True)
    for path in log_files(source):
        contents = read_file_contents(path)
        records = [record(r) for r in contents.records]
        writer = TrialLogWriter(target / path.name, contents.provenance or {})
        writer.provenance = provenance(dict(contents.provenance or {}))
        writer.run_id = records[0].run_id
        with writer as log:
            for changed in records:
                log.write(changed)
    return target


def identity_of(text: str, file: str) -> RunIdentity:
    """The identity of a run of the pipeline ``text``, recorded as found at ``file``."""
    pipeline = parse_pipeline(text, Path(file))
    return RunIdentity(pipeline.run_id, pipeline.name, file, text)


def as_run_of(identity: RunIdentity) -> dict[str, Callable]:
    """:func:`rewrite`'s changes that make a copy of the smoke run a run of ``identity``."""
    return {
        "provenance": lambda p: {**p, **identity.provenance()},
        "record": lambda r: msgspec.structs.replace(r, run_id=identity.run_id),
    }


def incomplete(run: Path) -> Path:
    """``run`` less one of its ``lambda_sweep`` files."""
    sorted(run.glob(f"lambda_sweep-*{LOG_SUFFIX}"))[0].unlink()
    return run


def files_of(directory: Path) -> dict[str, bytes]:
    """The files of a run directory and their bytes, but the lock a refused ``run`` takes."""
    return {
        p.name: p.read_bytes()
        for p in sorted(directory.iterdir())
        if p.is_file() and p.name != LOCK_NAME
    }


# --- escaping ---------------------------------------------------------------------------------

HOSTILE_TEXTS = [
    "main:s1\r\x1b[2KOK run data/runs/smoke: 14 file(s), 82 trials, design complete",
    "a\nb\tc\x00d\x7f\x9b[31m",
    "right-to-left \u202egnp.exe",
    "undecodable \udcff byte",
    "quote ' and \\ backslash",
]


@pytest.mark.parametrize("text", HOSTILE_TEXTS)
def test_terminal_text_is_printable_and_says_what_it_hides(text: str) -> None:
    shown = terminal(text)
    assert shown.isprintable()
    assert terminal(shown, limit=None) == shown  # escaping twice changes nothing
    assert "\r" not in shown and ("\\r" in shown) == ("\r" in text)


def test_terminal_text_is_bounded() -> None:
    shown = terminal("x" * 2**20)
    assert shown == "x" * TERMINAL_LIMIT + f"... ({2**20} characters)"
    assert terminal("y" * 10, limit=None) == "y" * 10


@pytest.mark.parametrize(
    "text", [*HOSTILE_TEXTS, "cfg/smoke.toml", "my runs/run 1", HOSTILE_FILE, "-x", "$(id)`id`"]
)
def test_a_shell_word_is_one_visible_argument(text: str) -> None:
    word = shell(text)
    assert word.isprintable()
    if text.isprintable():
        assert shlex.split(f"cirl-study run {word}") == ["cirl-study", "run", text]
    if shutil.which("bash") is not None and "\x00" not in text:
        echoed = subprocess.run(
            ["bash", "-c", f"printf %s {word}"], capture_output=True, check=True
        ).stdout
        assert echoed == os.fsencode(text), (word, echoed)


@pytest.mark.parametrize("text", [HOSTILE_NAME, "a`b``c", "`edge` ", "*x* _y_ [z](w)", "a\n# b"])
def test_markdown_shows_the_text_and_renders_none_of_it(text: str) -> None:
    markdown_it = pytest.importorskip("markdown_it")
    html = (
        markdown_it.MarkdownIt("commonmark").enable("table").render(f"# Report: {markdown(text)}")
    )
    assert html.startswith("<h1>Report: <code>") and html.endswith("</code></h1>\n"), html
    assert "<img" not in html and "<a " not in html and "<em>" not in html and "<h1>" in html
    assert markdown("paper") == "`paper`"  # a valid name reads as it always did


# --- provenance is checked against the pipeline text it carries --------------------------------


def _forged_text(provenance: dict[str, str], text: str) -> dict[str, str]:
    """``provenance`` carrying ``text``, with its hash (and the run id of its name) made to
    match, so that only the text itself is wrong."""
    identity = RunIdentity(provenance["run_id"], "smoke", provenance["pipeline_file"], text)
    return {**provenance, "pipeline_toml": text, "pipeline_sha256": identity.pipeline_sha256}


def _huge(provenance: dict[str, str]) -> dict[str, str]:
    """A pipeline of 40 million trials, its name, hash and run id all consistent."""
    text = SMOKE.read_text().replace(
        "subjects = 4\nrationality", "subjects = 10000000\nrationality"
    )
    forged = _forged_text(provenance, text)
    return {**forged, "run_id": f"smoke-{forged['pipeline_sha256'][:12]}"}


FORGERIES = {
    "pipeline_name holding markdown and HTML": (
        lambda p: {**p, "pipeline_name": HOSTILE_NAME},
        "provenance's pipeline_name",
    ),
    "run_id not of the name and hash": (
        lambda p: {**p, "run_id": "smoke-000000000000"},
        "provenance's run_id 'smoke-000000000000' is not the run id of its pipeline",
    ),
    "a pipeline name that is not a name": (
        lambda p: _forged_text(p, SMOKE.read_text().replace('"smoke"', '"<img src=x>"', 1)),
        "provenance's pipeline_toml: name must be letters, digits",
    ),
    "a pipeline that plans too many trials": (
        _huge,
        "provenance's pipeline_toml: plans 40000066 trials, more than the 2000000",
    ),
}


@pytest.mark.parametrize("forgery", FORGERIES)
def test_a_forged_provenance_is_refused_by_every_reader(
    tmp_path: Path, smoke_run: Path, forgery: str
) -> None:
    change, message = FORGERIES[forgery]
    run = rewrite(smoke_run, tmp_path / "run", provenance=change)
    before = files_of(run)
    first = log_files(run)[0]
    one_line(invoke("analyze", run), 2, f"{first}: unusable (no run identity: ", message)
    assert not (run / "report").exists()
    one_line(invoke("analyze", run, "--partial"), 2, message)
    one_line(invoke("run", SMOKE, "--out", run), 2, message)
    validated = invoke("validate", run)
    assert validated.exit_code == 1
    raw_free(validated.output)
    lines = validated.output.splitlines()
    assert all(line.startswith("FAIL ") and message in line for line in lines[:-1]), lines[0]
    assert lines[-1].startswith(f"FAIL run {run}: ")
    with pytest.raises(UserError, match=re.escape(message)):
        cirl_study.load_trials(run)
    assert files_of(run) == before  # nothing written, nothing lost


# --- trial ids and file names are shown, not obeyed ---------------------------------------------


def test_control_characters_in_trial_ids_cannot_forge_the_verdict(
    tmp_path: Path, smoke_run: Path
) -> None:
    forged = f"\r\x1b[2KOK run {tmp_path / 'run'}: 14 file(s), 82 trials, design complete"
    first = sorted(read_file_contents(log_files(smoke_run)[0]).records, key=lambda r: r.trial_id)

    def rename(record: TrialRecord) -> TrialRecord:
        if record.trial_id != first[0].trial_id:
            return record
        return msgspec.structs.replace(record, trial_id=record.trial_id + forged)

    run = rewrite(smoke_run, tmp_path / "run", record=rename)
    result = invoke("validate", run)
    assert result.exit_code == 1
    raw_free(result.output)
    last = result.output.splitlines()[-1]
    assert last.startswith("FAIL run ") and "\\r\\x1b[2KOK run" in last
    one_line(invoke("analyze", run), 2, "logged trial(s) the run's pipeline does not plan", "\\r")


def test_a_megabyte_trial_id_is_named_by_its_start_and_length(
    tmp_path: Path, smoke_run: Path
) -> None:
    huge = "main:" + "x" * 2**20
    target = read_file_contents(log_files(smoke_run)[0]).records[0].trial_id

    def rename(record: TrialRecord) -> TrialRecord:
        return (
            msgspec.structs.replace(record, trial_id=huge) if record.trial_id == target else record
        )

    run = rewrite(smoke_run, tmp_path / "run", record=rename)
    result = invoke("validate", run)
    assert result.exit_code == 1 and len(result.output) < 10_000
    assert f"... ({len(huge)} characters)" in result.output
    error = one_line(invoke("analyze", run), 2, f"... ({len(huge)} characters)")
    assert len(error) < 2_000


def test_a_file_name_with_control_characters_is_shown_escaped(
    tmp_path: Path, smoke_run: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run)
    victim = log_files(run)[0]
    victim.rename(run / f"x\r\x1b[2KOK{LOG_SUFFIX}")
    (run / f"y\r\x1b[2KOK{LOG_SUFFIX}").write_bytes(b"not a log")
    result = invoke("validate", run)
    assert result.exit_code == 1
    raw_free(result.output)
    assert "x\\r\\x1b[2KOK.mcap" in result.output
    one_line(invoke("analyze", run), 2, "y\\r\\x1b[2KOK.mcap")


# --- the advice: a run in progress, a changed pipeline, a command that works -------------------


def test_a_run_being_written_is_said_to_be_so_not_advised_to_resume(
    tmp_path: Path, smoke_run: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run)
    incomplete(run)
    (run / f"lambda_sweep-0000000000000000{LOG_SUFFIX}{TEMP_SUFFIX}").write_bytes(b"\x89MCAP0")
    being_written = f"a cirl-study run (pid {os.getpid()}) is still writing it"
    with writer_lock(run):
        assert writer_pid(run) == str(os.getpid())
        validated = invoke("validate", run)
        assert validated.exit_code == 1 and "resume with" not in validated.output
        assert being_written in validated.output.splitlines()[-1]
        analysed = invoke("analyze", run)
        assert (
            "resume with" not in analysed.stderr and "run the pipeline again" not in analysed.stderr
        )
        assert being_written in analysed.stderr.splitlines()[-1], analysed.stderr
        assert analysed.exit_code == 2 and not (run / "report").exists()
        linked = tmp_path / "linked"
        linked.mkdir()
        (linked / LOCK_NAME).symlink_to(run / LOCK_NAME)
        assert writer_pid(linked) is None  # a link is not a lock, nor followed
    assert writer_pid(run) is None
    assert "resume with `cirl-study run " in invoke("validate", run).output
    no_lock = tmp_path / "no-lock"
    no_lock.mkdir()
    assert writer_pid(no_lock) is None and not (no_lock / LOCK_NAME).exists()


def test_a_pipeline_of_changed_settings_is_another_run_named_with_both_ids(
    tmp_path: Path, smoke_run: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run)
    before = files_of(run)
    edited = tmp_path / "smoke.toml"
    edited.write_text(SMOKE.read_text().replace("seed = 7", "seed = 8"))
    new_id = load_pipeline(edited).run_id
    one_line(
        invoke("run", edited, "--out", run),
        2,
        f"{run}: holds run {SMOKE_RUN_ID}, made from another version of {edited}, which is now "
        f"run {new_id} with other settings; restore the settings",
    )
    assert files_of(run) == before


@pytest.mark.parametrize(
    "change",
    [
        lambda text: text + "# a note\n",
        lambda text: text.replace('description = "', 'description = "Edited: '),
        lambda text: text.replace("seed = 7", "seed   =   7  # the same seed"),
    ],
    ids=["a comment", "the description", "the layout"],
)
def test_a_pipeline_of_the_same_settings_resumes_its_run_and_says_so(
    tmp_path: Path, smoke_run: Path, change: Callable[[str], str]
) -> None:
    """A run is its settings: another text of them (a comment, the description, the layout)
    resumes the run, which keeps its id and the text it was made from."""
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run)
    before = files_of(run)
    edited = tmp_path / "smoke.toml"
    edited.write_text(change(SMOKE.read_text()))
    assert load_pipeline(edited).run_id != SMOKE_RUN_ID
    result = invoke("run", edited, "--out", run)
    assert result.exit_code == 0, result.output
    assert f"resuming run {SMOKE_RUN_ID}, made from another text of smoke with the same " in (
        result.stderr
    )
    assert f"run {SMOKE_RUN_ID}: 82 trials logged" in result.stdout
    assert files_of(run) == before


def test_the_advice_names_the_users_own_file_and_quotes_a_path_with_spaces(
    tmp_path: Path, smoke_run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A run of ``cfg/smoke.toml`` (not the shipped smoke pipeline: another seed) in
    ``my runs/run 1``: the advice runs that file into that directory."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cfg").mkdir()
    mine = Path("cfg/smoke.toml")
    mine.write_text(SMOKE.read_text().replace("seed = 7", "seed = 8"))
    identity = run_identity(load_pipeline(mine))
    assert identity.pipeline_file == "cfg/smoke.toml"
    run = incomplete(rewrite(smoke_run, Path("my runs/run 1"), **as_run_of(identity)))
    for result in (invoke("validate", run), invoke("analyze", run)):
        assert result.exit_code != 0
        command = advised_command(result.output)
        assert command == ["cirl-study", "run", "cfg/smoke.toml", "--out", "my runs/run 1"]
        assert load_pipeline(resolve_pipeline(command[2])).sha256 == identity.pipeline_sha256
    Path("smoke.toml").write_text(mine.read_text())
    assert run_identity(load_pipeline(Path("smoke.toml"))).pipeline_file == "./smoke.toml"
    assert run_identity(load_pipeline(SMOKE)).pipeline_file == str(SMOKE)  # outside: absolute


def test_a_hostile_pipeline_file_is_never_part_of_a_command(
    tmp_path: Path, smoke_run: Path
) -> None:
    smoke = rewrite(smoke_run, tmp_path / "smoke", lambda p: {**p, "pipeline_file": HOSTILE_FILE})
    command = advised_command(invoke("validate", incomplete(smoke)).output)
    assert command[:2] == ["cirl-study", "run"] and command[3:] == ["--out", str(smoke)]
    assert load_pipeline(Path(command[2])).run_id == SMOKE_RUN_ID  # the shipped file holds it
    mine = identity_of(SMOKE.read_text().replace('"smoke"', '"mine"', 1), HOSTILE_FILE)
    other = incomplete(rewrite(smoke_run, tmp_path / "mine", **as_run_of(mine)))
    validated = invoke("validate", other)
    raw_free(validated.output)
    assert advised_command(validated.output) == [
        "cirl-study",
        "run",
        "PIPELINE",
        "--out",
        str(other),
    ]
    assert f"sha256 {mine.pipeline_sha256[:12]}..." in validated.output
    error = one_line(invoke("analyze", other), 2, "resume with `cirl-study run PIPELINE --out")
    assert "touch PWNED" not in error.split("`")[1]


def test_every_csv_we_write_is_safe_to_open_in_a_spreadsheet(tmp_path: Path) -> None:
    """A text cell or header a spreadsheet would run as a formula (OWASP: it starts with
    =, +, -, @, a tab or a carriage return) is written with a leading apostrophe; numbers,
    negative ones too, are written as they are; the frame itself is not changed."""
    import pandas as pd

    from cirl_study.analysis.report.output import csv_file, write_report_directory

    frame = pd.DataFrame(
        {
            "subject": ['=HYPERLINK("http://x","y")', "+1", "-2", "@SUM(A1)", "\tx", "main"],
            "regret": [-0.5, 0.25, -1.0, 0.0, 1.0, 2.0],
            "=cmd": ["a", "b", "c", "d", "e", "f"],
        }
    )
    expected = (
        "subject,regret,'=cmd\n"
        '"\'=HYPERLINK(""http://x"",""y"")",-0.5,a\n'
        "'+1,0.25,b\n'-2,-1.0,c\n'@SUM(A1),0.0,d\n'\tx,1.0,e\nmain,2.0,f\n"
    )
    assert csv_file(frame).decode() == expected
    write_report_directory(
        tmp_path, markdown="", results={}, tables={"t.csv": frame}, figures={}, provenance=None
    )
    assert (tmp_path / "t.csv").read_text() == expected
    assert frame["subject"].iloc[1] == "+1"
