"""What the command line and the log reader load before the first log file is read: nothing
of the numerical core, the analysis libraries, the log writer or rich, which only the
commands that use them load (``analyze`` starts reading after these imports alone)."""

from __future__ import annotations

import subprocess
import sys

HEAVY = (
    "numba",
    "cirl_study.core.trial",
    "pandas",
    "scipy",
    "matplotlib",
    "pingouin",
    "rich",
    "mcap.writer",
    "cirl_study.logs.writer",
    "importlib.metadata",
)
"""Modules the start-up must not load, each tens to hundreds of milliseconds."""


def test_the_command_line_and_the_reader_load_nothing_heavy() -> None:
    script = (
        "import sys\n"
        "import cirl_study.cli, cirl_study.logs.reader\n"
        f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True
    )
    assert done.stdout.split() == []
