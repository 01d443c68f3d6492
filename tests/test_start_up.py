"""How the command line starts: what it and the log reader load before the first log file is
read (nothing of the numerical core, the analysis libraries, the log writer or rich, which
only the commands that use them load: ``analyze`` starts reading after these imports alone),
and the one thread each numerical library is given before it loads."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from cirl_study.__main__ import ONE_THREAD

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


def test_the_command_lines_numerical_libraries_compute_on_one_thread() -> None:
    """Every BLAS library, numpy's (loaded with the command line) and those loaded later by a
    command (scipy's, when its wheel brings its own), runs one thread under ``cirl-study``; a
    value the user set is kept."""
    script = (
        "import json, os, sys\n"
        "sys.argv = ['cirl-study', '--version']\n"
        "from cirl_study.__main__ import console_script\n"
        "try:\n"
        "    console_script()\n"
        "except SystemExit:\n"
        "    pass\n"
        "import scipy.linalg\n"
        "from threadpoolctl import threadpool_info\n"
        "blas = {i['filepath']: i['num_threads'] for i in threadpool_info()\n"
        "        if i['user_api'] == 'blas'}\n"
        "print(json.dumps([os.environ['MKL_NUM_THREADS'], blas]))\n"
    )
    unset = {name: value for name, value in os.environ.items() if name not in ONE_THREAD}
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        check=True,
        env={**unset, "MKL_NUM_THREADS": "3"},
    )
    mkl, blas = json.loads(done.stdout.splitlines()[-1])
    assert mkl == "3"
    assert set(blas.values()) == {1}
