"""Every ``--help`` renders cleanly at 80 columns: no line too long, paragraphs reflowed,
flags shown without a value, arguments in the usage line as click writes them (``RUN``,
``[PIPELINE]``); every value an option does not take is refused in one plain line."""

from __future__ import annotations

from typing import Annotated

import pytest
import typer
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.commands.parameters import Command

USAGES = {
    "run": "[OPTIONS] [PIPELINE]",
    "serve": "[OPTIONS] PIPELINE",
    "validate": "[OPTIONS] RUN",
    "analyze": "[OPTIONS] RUN",
    "reproduce": "[OPTIONS] [PIPELINE]",
    "compare": "[OPTIONS] EXPECTED GOT",
    "office-supplies": "[OPTIONS]",
}
COMMANDS = list(USAGES)


def _help(*command: str) -> str:
    result = CliRunner().invoke(app, [*command, "--help"], env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    return result.output


@pytest.mark.parametrize("command", [[], *([c] for c in COMMANDS)])
def test_help_renders_at_80_columns(command: list[str]) -> None:
    text = _help(*command)
    lines = text.splitlines()
    assert all(len(line) <= 80 for line in lines), max(lines, key=len)
    assert "<bool>" not in text
    usage = lines[0]
    if command:
        assert usage == f"Usage: cirl-study {command[0]} {USAGES[command[0]]}"
    else:
        assert usage == "Usage: cirl-study [OPTIONS] COMMAND [ARGS]..."
    # Reflowed paragraphs: a description line never breaks far short of the width while
    # its paragraph goes on (a hard-wrapped docstring leaves short orphan lines).
    description = text.split("\n\n")[1:]
    for paragraph in description:
        body = [line for line in paragraph.splitlines() if line.startswith("  ") and
                not line.startswith("   ") and not line.strip().startswith("-")]  # fmt: skip
        for line, following in zip(body, body[1:], strict=False):
            if following.strip() and not line.rstrip().endswith((":", ".")):
                assert len(line) > 50, f"{line!r} then {following!r}"


def test_the_usage_line_of_an_error_names_the_arguments_alike() -> None:
    result = CliRunner().invoke(app, ["compare", "only-one"])
    assert result.exit_code == 2
    assert result.stderr.startswith(f"Usage: cirl-study compare {USAGES['compare']}\n")
    assert result.stderr.rstrip().endswith("Error: Missing argument 'GOT'.")


def _options_taking_a_value() -> list[tuple[str, str]]:
    group = typer.main.get_command(app)
    return [
        (name, param.opts[0])
        for name, command in group.commands.items()
        for param in command.params
        if param.param_type_name == "option" and not param.is_flag
    ]


FAILING_ARGUMENTS = {
    "run": ["no/such.toml"],
    "serve": ["no/such.toml"],
    "reproduce": ["no/such.toml"],
    "validate": ["no/such/run"],
    "analyze": ["no/such/run"],
    "calibrate": ["no/such/run", "--target", "no/such.csv"],
    "compare": ["no/such/a", "no/such/b"],
}
"""Arguments each command refuses, once its options are parsed, before doing anything."""

BAD_VALUES = {
    ("run", "--engine"): ("foo", "'foo' is not one of: local, dask."),
    ("reproduce", "--engine"): ("DASK", "'DASK' is not one of: local, dask."),
    ("run", "--workers"): ("2.5", "'2.5' is not an integer."),
    ("run", "--no-workers-timeout"): ("soon", "'soon' is not a number of seconds."),
    ("reproduce", "--workers"): ("many", "'many' is not an integer."),
    ("calibrate", "--max-probes"): ("3.5", "'3.5' is not an integer."),
    ("calibrate", "--workers"): ("all", "'all' is not an integer."),
    ("compare", "--rtol"): ("-1e-9", "'-1e-9' is not a number >= 0."),
    ("compare", "--atol"): ("nan", "'nan' is not a number >= 0."),
    ("serve", "--port"): ("65536", "'65536' is not a port number (0 to 65535)."),
}
"""The options whose value is checked as it is parsed, each with a value it refuses."""


def test_every_option_taking_a_value_is_tried() -> None:
    assert set(BAD_VALUES) <= set(_options_taking_a_value())
    assert {name for name, _ in _options_taking_a_value()} <= set(FAILING_ARGUMENTS)


@pytest.mark.parametrize(("command", "option"), _options_taking_a_value())
def test_a_value_an_option_does_not_take_is_one_plain_line(
    command: str, option: str, tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Checked options refuse a bad value in click's one line, in plain words, the value
    escaped; the others take any text, and the command then refuses its arguments."""
    monkeypatch.chdir(tmp_path)
    value, message = BAD_VALUES.get((command, option), ("any\x1b[2J\r", None))
    for tried, said in ((value, message), (f"{value}\x1b[2J\r", None)):
        result = CliRunner().invoke(app, [command, *FAILING_ARGUMENTS[command], option, tried])
        assert result.exit_code == 2, result.output
        assert all(line.isprintable() for line in result.stderr.splitlines()), result.stderr
        last = result.stderr.splitlines()[-1]
        assert "Value error" not in last and "Input should" not in last, last
        if (command, option) not in BAD_VALUES:
            assert last.startswith("error: "), last  # the value was taken
        elif said is not None:
            assert last == f"Error: Invalid value for '{option}': {said}"
        else:
            assert last.startswith(f"Error: Invalid value for '{option}': '{value}\\x1b[2J\\r'")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("arguments", "exit_code", "output"),
    [(["--version"], 0, "cirl-study "), (["analyze", "no/such/run"], 2, "error: ")],
)
def test_the_console_script_exits_with_the_commands_code(arguments, exit_code, output, tmp_path):
    import subprocess
    import sys

    command = [sys.executable, "-m", "cirl_study", *arguments]
    done = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, check=False)
    assert done.returncode == exit_code
    assert (done.stdout + done.stderr).startswith(output)
    assert "Traceback" not in done.stderr


def test_the_engine_help_names_commands_that_work_as_printed() -> None:
    text = " ".join(_help("run").split())
    assert "\\[" not in text
    assert "pip install -e '.[dask]' in a checkout" in text and "'cirl-study[dask]'" in text


def test_the_usage_line_marks_optional_and_repeated_arguments_as_click_does() -> None:
    sample = typer.Typer(rich_markup_mode=None)

    @sample.command(cls=Command)
    def main(
        first: Annotated[str, typer.Argument(metavar="FIRST")],
        files: Annotated[list[str], typer.Argument()],
        last: Annotated[str, typer.Argument(metavar="LAST")] = "x",
    ) -> None:
        """A command of three arguments."""

    usage = CliRunner().invoke(sample, ["--help"]).output.splitlines()[0]
    assert usage == "Usage: main [OPTIONS] FIRST FILES... [LAST]"
