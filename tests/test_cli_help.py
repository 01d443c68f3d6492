"""Every ``--help`` renders cleanly at 80 columns: no line too long, paragraphs reflowed,
flags shown without a value, argument names in capitals."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from cirl_study.cli import app

COMMANDS = ["run", "validate", "analyze", "reproduce", "compare", "office-supplies"]


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
    assert usage.startswith(f"Usage: cirl-study {' '.join(command)}".rstrip())
    assert not re.search(r"\{[a-z]", usage), usage  # arguments by capital names
    # Reflowed paragraphs: a description line never breaks far short of the width while
    # its paragraph goes on (a hard-wrapped docstring leaves short orphan lines).
    description = text.split("\n\n")[1:]
    for paragraph in description:
        body = [line for line in paragraph.splitlines() if line.startswith("  ") and
                not line.startswith("   ") and not line.strip().startswith("-")]  # fmt: skip
        for line, following in zip(body, body[1:], strict=False):
            if following.strip() and not line.rstrip().endswith((":", ".")):
                assert len(line) > 50, f"{line!r} then {following!r}"


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
