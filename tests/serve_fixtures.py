"""A small pipeline that collects demonstrations, and legal paths of its game, for the tests
of ``cirl-study serve`` (its API, its page in a browser) and its load benchmark."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SHIPPED = (REPO / "pipelines" / "people-browser.toml").read_text()

EXPERIMENT = '''
[tasks]
oox = { orange = 0, purple = 0, cyan = -1, step = -0.1 }
xoo = { orange = -1, purple = 0, cyan = 0, step = -0.1 }
oxo = { orange = 0, purple = -1, cyan = 0, step = -0.1 }

[participants]
collect = true
conditions = ["do", "show"]

[experiment]
consent = """
You agree to take part.

Your moves are recorded.
"""
instructions.do = "Reach the yellow goal."
instructions.show = "Show the robot which colours are safe."
practice = { orange = -1, purple = 0, cyan = 0, step = -0.1 }
completion_code = "DONE-7"
participant_parameter = "PROLIFIC_PID"

'''

COLLECTING = (
    'name = "collect-test"\ndescription = "Tiles in a browser"\nseed = 7\n\n'
    + SHIPPED[SHIPPED.index("[game]") : SHIPPED.index("[tasks]")]
    + EXPERIMENT
    + SHIPPED[SHIPPED.index("[eta_cv]") : SHIPPED.index("[main]")]
    + '[main]\nrationality = 1.0\nhumans = ["expert", "recorded"]\nrobots = ["map"]\n'
)
"""The shipped browser study's game (Ho et al.'s tiles) with three of its tasks, two
conditions between participants, and the expert beside the people."""

CHROMIUM = Path("/usr/bin/chromium")
"""Debian's Chromium, which Playwright drives (its own browser download is not used)."""

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
"""Chromium's flags: no sandbox (root), and no connection of its own to anywhere."""

STRAIGHT = [[0, 2], [1, 2], [2, 2], [3, 2], [4, 2], [5, 2]]
"""The shortest path to the goal: right along the middle row (5 moves)."""

ROUND_THE_TOP = [[0, 2], [0, 3], [0, 4], [1, 4], [2, 4], [3, 4], [4, 4], [5, 4], [5, 3], [5, 2]]
"""Up the left column, along the top row and down to the goal (9 moves)."""

ROUND_THE_BOTTOM = [[0, 2], [0, 1], [0, 0], [1, 0], [2, 0], [3, 0], [4, 0], [5, 0], [5, 1], [5, 2]]
"""Down the left column, along the bottom row and up to the goal (9 moves)."""

MOVES = {(0, 1): "ArrowUp", (0, -1): "ArrowDown", (1, 0): "ArrowRight", (-1, 0): "ArrowLeft"}
"""The arrow key of each move (``y`` grows upward: the layout's top row is ``y = 4``)."""


def write_pipeline(directory: Path, text: str = COLLECTING) -> Path:
    """The pipeline ``text`` as a file in ``directory``."""
    path = directory / "collect.toml"
    path.write_text(text)
    return path


def free_port() -> int:
    """A port free on 127.0.0.1 now."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def start_server(pipeline: Path, run_dir: Path, port: int) -> tuple[subprocess.Popen[str], str]:
    """``cirl-study serve`` in a process of its own, and its experimenter's token, once it
    answers."""
    process = subprocess.Popen(
        [sys.executable, "-m", "cirl_study", "serve", str(pipeline), "--out", str(run_dir),
         "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    assert process.stdout is not None
    token = None
    for line in process.stdout:
        if line.startswith("experimenter: "):
            token = line.strip().rsplit("key=", 1)[1]
            break
    if token is None:
        process.wait(10)
        raise AssertionError(f"serve did not start: {process.stderr.read()}")  # type: ignore[union-attr]
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                return process, token
        except OSError:
            time.sleep(0.05)
    process.kill()
    raise AssertionError("serve did not answer in 30 s")


def through_api(port: int, participant: str, path: list[list[int]]) -> None:
    """``participant`` through the running server on ``port`` by its HTTP API, as the page
    goes, every task (and the practice) by ``path``, 0.5 s a move."""
    import json
    import urllib.request

    def call(route: str, token: str | None = None, body: object = None) -> dict:
        headers = {"Content-Type": "application/json"}
        if token is not None:
            headers["Authorization"] = f"Bearer {token}"
        data = None if body is None else json.dumps(body).encode()
        method = "GET" if body is None and route == "state" else "POST"
        request = urllib.request.Request(
            f"http://127.0.0.1:{port}/api/{route}", data=data, headers=headers, method=method
        )
        with urllib.request.urlopen(request, timeout=60) as response:
            return json.loads(response.read())

    state = call("start", body={"participant": participant})
    token = state["token"]
    while state["stage"] != "done":
        if state["stage"] in ("consent", "instructions"):
            state = call(state["stage"], token)
            continue
        shown = {
            "task": state["task"]["name"],
            "path": path,
            "seconds": [0.5 * step for step in range(len(path))],
        }
        state = call("practice" if state["stage"] == "practice" else "demonstration", token, shown)
