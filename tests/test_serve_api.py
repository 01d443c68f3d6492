"""``cirl-study serve``'s HTTP API: the participant's way through, validation on the server,
ownership of sessions, bounded requests, resume, no double submission, assignment, the
experimenter's status, and the run directory's lock."""

from __future__ import annotations

import collections
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from serve_fixtures import (
    COLLECTING,
    ROUND_THE_BOTTOM,
    ROUND_THE_TOP,
    STRAIGHT,
    free_port,
    start_server,
    write_pipeline,
)
from starlette.testclient import TestClient

from cirl_study.errors import UserError
from cirl_study.logs.collection import collected
from cirl_study.logs.lock import writer_lock
from cirl_study.serve.app import body_limit, create_app
from cirl_study.serve.assignment import assign, latin_square
from cirl_study.serve.experiment import Experiment
from cirl_study.serve.sessions import SESSIONS_DIRECTORY
from cirl_study.study.pipeline_file import load_pipeline

KEY = "experimenter-key"


@pytest.fixture
def pipeline_file(tmp_path: Path) -> Path:
    return write_pipeline(tmp_path)


def client(pipeline_file: Path, run_dir: Path) -> TestClient:
    """A client of a new server of the pipeline on ``run_dir`` (a restart, if it was served)."""
    run_dir.mkdir(exist_ok=True)
    experiment = Experiment(load_pipeline(pipeline_file), run_dir)
    return TestClient(create_app(experiment, KEY))


def seconds(path: list[list[int]]) -> list[float]:
    return [round(0.5 * t + 0.25 * (t > 0), 3) for t in range(len(path))]


def shown(task: str, path: list[list[int]]) -> dict:
    return {"task": task, "path": path, "seconds": seconds(path)}


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def begin(http: TestClient, participant: str | None = None) -> tuple[str, dict]:
    """A new session through consent, instructions and practice: its token, its first task."""
    state = http.post("/api/start", json={"participant": participant}).json()
    token = state["token"]
    assert state["stage"] == "consent"
    assert http.post("/api/consent", headers=bearer(token)).json()["stage"] == "instructions"
    assert http.post("/api/instructions", headers=bearer(token)).json()["stage"] == "practice"
    state = http.post(
        "/api/practice", headers=bearer(token), json=shown("practice", ROUND_THE_BOTTOM)
    ).json()
    assert state["stage"] == "task"
    return token, state


def finish(http: TestClient, token: str, state: dict) -> dict:
    """Every remaining task of the session of ``token`` submitted, by the straight path."""
    while state["stage"] == "task":
        answer = http.post(
            "/api/demonstration", headers=bearer(token), json=shown(state["task"]["name"], STRAIGHT)
        )
        assert answer.status_code == 200, answer.text
        state = answer.json()
    return state


def test_a_participant_goes_through_and_every_demonstration_is_stored(
    pipeline_file: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    http = client(pipeline_file, run)
    setup = http.get("/api/setup").json()
    assert setup["participant_parameter"] == "PROLIFIC_PID"
    assert setup["board"]["start"] == [0, 2] and setup["board"]["max_moves"] == 13
    assert {tile["letter"] for tile in setup["board"]["tiles"].values()} == {"O", "P", "C", "Y", ""}

    state = http.post("/api/start", json={"participant": "P01"}).json()
    token = state["token"]
    assert (state["participant"], state["stage"], state["count"]) == ("P01", "consent", 3)
    assert "You agree to take part." in state["text"]
    state = http.post("/api/consent", headers=bearer(token)).json()
    assert state["stage"] == "instructions" and state["condition"] in ("do", "show")
    condition = state["condition"]
    assert state["text"] == {"do": "Reach the yellow goal.", "show": "Show the robot which "
                             "colours are safe."}[condition]  # fmt: skip
    state = http.post("/api/instructions", headers=bearer(token)).json()
    assert state["stage"] == "practice" and state["task"]["practice"]
    legend = {meaning["feature"]: meaning["kind"] for meaning in state["task"]["legend"]}
    assert legend == {"orange": "dangerous", "purple": "safe", "cyan": "safe"}
    assert state["task"]["move_weight"] == -0.1

    # The practice is checked as a demonstration is, and not stored.
    jump = shown("practice", [[0, 2], [2, 2], [3, 2], [4, 2], [5, 2]])
    refused = http.post("/api/practice", headers=bearer(token), json=jump)
    assert refused.status_code == 400 and "jumps" in refused.json()["error"]
    state = http.post(
        "/api/practice", headers=bearer(token), json=shown("practice", ROUND_THE_TOP)
    ).json()
    assert state["stage"] == "task" and state["task"]["number"] == 1
    assert collected(run, load_pipeline(pipeline_file).run_id) == []

    paths = {}
    for path in (STRAIGHT, ROUND_THE_TOP, ROUND_THE_BOTTOM):
        task = state["task"]["name"]
        later = [name for name in ("oox", "xoo", "oxo") if name not in (task, *paths)]
        for other in later:
            wrong = http.post("/api/demonstration", headers=bearer(token), json=shown(other, path))
            assert wrong.status_code == 409 and "current task" in wrong.json()["error"]
        short = http.post("/api/demonstration", headers=bearer(token), json=shown(task, path[:-1]))
        assert short.status_code == 400 and "not in a goal" in short.json()["error"]
        answer = http.post("/api/demonstration", headers=bearer(token), json=shown(task, path))
        assert answer.status_code == 200, answer.text
        paths[task] = path
        state = answer.json()
    assert state["stage"] == "done" and state["completion_code"] == "DONE-7"
    assert state["done"] == state["count"] == 3

    stored = collected(run, load_pipeline(pipeline_file).run_id)
    assert sorted(s.task for s in stored) == ["oox", "oxo", "xoo"]
    for demonstration in stored:
        recorded = demonstration.recorded
        assert recorded.participant == "P01" and recorded.condition == condition
        assert [list(cell) for cell in recorded.path] == paths[demonstration.task]
        assert list(recorded.seconds) == seconds(paths[demonstration.task])
    assert sorted(s.recorded.order for s in stored) == [1, 2, 3]


def test_a_submission_again_is_answered_alike_and_stores_nothing_more(
    pipeline_file: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    http = client(pipeline_file, run)
    token, state = begin(http, "P02")
    task = state["task"]["name"]
    first = http.post("/api/demonstration", headers=bearer(token), json=shown(task, STRAIGHT))
    again = http.post("/api/demonstration", headers=bearer(token), json=shown(task, STRAIGHT))
    assert first.status_code == again.status_code == 200
    assert first.json() == again.json()
    other = http.post("/api/demonstration", headers=bearer(token), json=shown(task, ROUND_THE_TOP))
    assert other.status_code == 409 and "stored already" in other.json()["error"]
    state = finish(http, token, first.json())
    late = http.post("/api/demonstration", headers=bearer(token), json=shown("oox", ROUND_THE_TOP))
    assert late.status_code == 409
    assert len(collected(run, load_pipeline(pipeline_file).run_id)) == 3
    # A finished participant who comes back is at the end.
    back = http.post("/api/start", json={"participant": "P02"}).json()
    assert back["stage"] == "done" and back["completion_code"] == "DONE-7"


def test_a_session_acts_only_for_itself(pipeline_file: Path, tmp_path: Path) -> None:
    http = client(pipeline_file, tmp_path / "run")
    first, state = begin(http, "P03")
    second, _ = begin(http, "P04")
    assert http.get("/api/state", headers=bearer(first)).json()["participant"] == "P03"
    assert http.get("/api/state", headers=bearer(second)).json()["participant"] == "P04"
    for headers in ({}, bearer("not-a-token"), {"Authorization": "Basic abc"}):
        answer = http.post(
            "/api/demonstration", headers=headers, json=shown(state["task"]["name"], STRAIGHT)
        )
        assert answer.status_code == 401
        assert http.get("/api/state", headers=headers).status_code == 401
    # The page's address cannot name another participant into a session it holds the token of.
    other = http.post("/api/start", json={"participant": "P05", "token": first}).json()
    assert other["participant"] == "P05" and other["token"] not in (first, None)


def test_requests_are_bounded_and_typed(pipeline_file: Path, tmp_path: Path) -> None:
    http = client(pipeline_file, tmp_path / "run")
    token, state = begin(http, "P06")
    limit = body_limit(13)
    big = json.dumps(shown(state["task"]["name"], STRAIGHT * 10_000))
    assert len(big) > limit
    answer = http.post("/api/demonstration", headers=bearer(token), content=big)
    assert answer.status_code == 413 and str(limit) in answer.json()["error"]

    def chunks():  # no Content-Length: read only up to the bound
        yield b'{"task": "oox", "path": ['
        for _ in range(limit):
            yield b"[0, 2],"

    answer = http.post("/api/demonstration", headers=bearer(token), content=chunks())
    assert answer.status_code == 413
    for body in (
        b"not json",
        b'{"task": "oox"}',
        b'{"task": "oox", "path": [[0, 2]], "seconds": [0], "name": "x"}',
        b'{"task": "oox", "path": [[0, 2.5]], "seconds": [0]}',
        b'{"task": "oox", "path": [[0, 2]], "seconds": [-1]}',
        b'{"task": "oox", "path": [[0, 99999999999]], "seconds": [0]}',
    ):
        answer = http.post("/api/demonstration", headers=bearer(token), content=body)
        assert answer.status_code == 400, body
        assert "\n" not in answer.json()["error"]
    task = state["task"]["name"]
    off = http.post(
        "/api/demonstration", headers=bearer(token), json=shown(task, [[0, 2], [-1, 2]])
    )
    assert off.status_code == 400
    uneven = {"task": task, "path": STRAIGHT, "seconds": [0.0]}
    answer = http.post("/api/demonstration", headers=bearer(token), json=uneven)
    assert answer.status_code == 400 and "each cell has its time" in answer.json()["error"]
    bad_id = http.post("/api/start", json={"participant": "../../etc/passwd"})
    assert bad_id.status_code == 400
    assert http.post("/api/start", content=b'{"participant": 5}').status_code == 400


def test_a_participant_resumes_after_a_reload_another_browser_and_a_restart(
    pipeline_file: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    http = client(pipeline_file, run)
    token, state = begin(http, "P07")
    task = state["task"]["name"]
    state = http.post(
        "/api/demonstration", headers=bearer(token), json=shown(task, STRAIGHT)
    ).json()
    # A reload: the page holds its token.
    reloaded = http.post("/api/start", json={"participant": "P07", "token": token}).json()
    assert reloaded["token"] is None and reloaded["task"] == state["task"]
    # The server restarts (a kill): sessions and the store are read back.
    http = client(pipeline_file, run)
    assert http.get("/api/state", headers=bearer(token)).json()["task"] == state["task"]
    # Another browser, by the platform's id: a new token; the old one is retired.
    elsewhere = http.post("/api/start", json={"participant": "P07"}).json()
    assert elsewhere["task"] == state["task"] and elsewhere["token"] not in (None, token)
    assert http.get("/api/state", headers=bearer(token)).status_code == 401
    assert finish(http, elsewhere["token"], elsewhere)["stage"] == "done"
    # Without a platform id, a random one, resumed by the page's token alone.
    anonymous = http.post("/api/start", json={}).json()
    assert anonymous["participant"].startswith("R-")
    again = http.post("/api/start", json={"token": anonymous["token"]}).json()
    assert again["participant"] == anonymous["participant"]


def test_stages_go_in_order(pipeline_file: Path, tmp_path: Path) -> None:
    http = client(pipeline_file, tmp_path / "run")
    token = http.post("/api/start", json={}).json()["token"]
    early = http.post("/api/demonstration", headers=bearer(token), json=shown("oox", STRAIGHT))
    assert early.status_code == 409 and "at the consent" in early.json()["error"]
    assert http.post("/api/instructions", headers=bearer(token)).status_code == 409
    assert http.post("/api/consent", headers=bearer(token)).status_code == 200
    # Agreeing again (a page that lost the answer) changes nothing.
    assert http.post("/api/consent", headers=bearer(token)).json()["stage"] == "instructions"


def test_conditions_are_blocked_and_task_orders_a_latin_square(
    pipeline_file: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    http = client(pipeline_file, run)
    for index in range(12):
        http.post("/api/start", json={"participant": f"Q{index:02d}"})
    sessions = [
        json.loads((run / SESSIONS_DIRECTORY / f"Q{index:02d}.json").read_text())
        for index in range(12)
    ]
    steps = [[tuple(step) for step in s["assignment"]["steps"]] for s in sessions]
    conditions = [s[0][0] for s in steps]
    for block in range(6):
        assert sorted(conditions[2 * block : 2 * block + 2]) == ["do", "show"]
    # Each condition cycles through the six rows of the square of three tasks (odd: 2 x 3).
    for condition in ("do", "show"):
        orders = [tuple(task for _, task in s) for s in steps if s[0][0] == condition]
        assert len(set(orders)) == 6
        positions = collections.Counter((order.index(t), t) for order in orders for t in order)
        assert set(positions.values()) == {2}
    # The assignment logged is the one derived from the seed and the arrival.
    for index, session in enumerate(sessions):
        derived = assign(7, index, ("do", "show"), ("oox", "xoo", "oxo"), within=False)
        assert [list(step) for step in derived.steps] == session["assignment"]["steps"]
    assert latin_square(4)[1] == [1, 2, 0, 3]


def test_within_participants_see_each_condition_s_instructions(tmp_path: Path) -> None:
    pipeline_file = write_pipeline(
        tmp_path,
        COLLECTING.replace(
            'conditions = ["do", "show"]', 'conditions = ["do", "show"]\ndesign = "within"'
        ),
    )
    http = client(pipeline_file, tmp_path / "run")
    token, state = begin(http, "W01")
    seen = [state["condition"]]
    for _ in range(6):
        if state["stage"] == "instructions":
            seen.append(state["condition"])
            state = http.post("/api/instructions", headers=bearer(token)).json()
        answer = http.post(
            "/api/demonstration", headers=bearer(token), json=shown(state["task"]["name"], STRAIGHT)
        )
        state = answer.json()
    assert state["stage"] == "done" and sorted(seen) == ["do", "show"]


def test_the_status_is_the_experimenter_s(pipeline_file: Path, tmp_path: Path) -> None:
    http = client(pipeline_file, tmp_path / "run")
    token, state = begin(http, "S01")
    finish(http, token, state)
    begin(http, "S02")
    assert http.get("/api/status").status_code == 403
    assert http.get("/api/status", params={"key": "wrong"}).status_code == 403
    status = http.get("/api/status", headers=bearer(KEY)).json()
    rows = {row["condition"]: row for row in status["conditions"]}
    assert status["participants"] == 2
    assert sum(row["started"] for row in rows.values()) == 2
    assert sum(row["finished"] for row in rows.values()) == 1
    assert sum(row["demonstrations"] for row in rows.values()) == 3
    page = http.get("/status", params={"key": KEY})
    assert page.status_code == 200 and "finished" in page.text
    assert http.get("/status").status_code == 403


def test_only_the_page_s_own_files_are_served(pipeline_file: Path, tmp_path: Path) -> None:
    http = client(pipeline_file, tmp_path / "run")
    page = http.get("/")
    assert page.status_code == 200 and "experiment.js" in page.text
    assert "script-src 'self'" in page.headers["content-security-policy"]
    assert page.headers["cache-control"] == "no-store"
    for name in ("experiment.js", "experiment.css"):
        assert http.get(f"/{name}").status_code == 200
    for path in ("/page/index.html", "/../collect.toml", "/sessions", "/collected", "/app.py"):
        assert http.get(path).status_code == 404
    # The page loads nothing from elsewhere.
    for name in ("index.html", "experiment.js", "experiment.css"):
        text = http.get("/" if name == "index.html" else f"/{name}").text
        assert "http://" not in text and "https://" not in text and "//cdn" not in text


def test_a_pipeline_without_an_experiment_is_not_served(tmp_path: Path) -> None:
    pipeline_file = write_pipeline(
        tmp_path,
        COLLECTING[: COLLECTING.index("[experiment]")] + COLLECTING[COLLECTING.index("[eta_cv]") :],
    )
    with pytest.raises(UserError, match="has no \\[experiment\\] table"):
        Experiment(load_pipeline(pipeline_file), tmp_path / "run")


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (("collect = true", 'file = "x.csv"'), "experiment must not be given unless"),
        (('instructions.show = "Show the robot which colours are safe."\n', ""),
         "experiment.instructions must give every condition its text; show is missing"),
        (('instructions.do = "', 'instructions.maybe = "x"\ninstructions.do = "'),
         "experiment.instructions.maybe is not one of participants.conditions"),
        (("practice = {", 'practice = "no"\nxpractice = {'), "experiment.practice must be one of"),
        (('completion_code = "DONE-7"', 'completion_code = "D"\ncompletion_url = "https://x/"'),
         "exactly one of them"),
        (('completion_code = "DONE-7"', 'completion_url = "javascript:alert(1)"'),
         "experiment.completion_url must be an https://"),
        (('completion_code = "DONE-7"', ""), "exactly one of them"),
        (('participant_parameter = "PROLIFIC_PID"', 'participant_parameter = "a b"'),
         "experiment.participant_parameter must be a URL parameter"),
        (('consent = """', 'consent = """' + "x" * 20_001), "experiment.consent must be at most"),
        (("practice = { orange = -1,", "practice = { orange = -2,"),
         "experiment.practice.orange must be a number in [-1, 1]"),
    ],
)  # fmt: skip
def test_an_experiment_table_is_checked(tmp_path: Path, edit, expected: str) -> None:
    text = COLLECTING.replace(*edit)
    assert text != COLLECTING
    if "xpractice" in text:
        text = text.replace("xpractice = {", "# {")
    rows = [f"{p},do,oox,{t},{x},{y}" for p in ("A", "B") for t, (x, y) in enumerate(STRAIGHT)]
    (tmp_path / "x.csv").write_text("participant,condition,task,step,x,y\n" + "\n".join(rows))
    with pytest.raises(UserError) as raised:
        load_pipeline(write_pipeline(tmp_path, text))
    assert expected in str(raised.value)


def test_the_run_directory_is_served_by_one_writer(pipeline_file: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    port = free_port()
    process, _ = start_server(pipeline_file, run, port)
    try:
        second = subprocess.run(
            [sys.executable, "-m", "cirl_study", "serve", str(pipeline_file), "--out", str(run),
             "--port", str(free_port())],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert second.returncode == 2
        assert second.stderr.count("\n") == 1 and f"pid {process.pid}" in second.stderr
        with pytest.raises(UserError, match="another cirl-study run"), writer_lock(run):
            pass
    finally:
        process.terminate()
        process.wait(30)
    with writer_lock(run):  # released when the server ends
        pass


def test_serving_a_pipeline_that_collects_nothing_is_one_line(tmp_path: Path) -> None:
    people = Path(__file__).resolve().parent.parent / "pipelines" / "people.toml"
    answer = subprocess.run(
        [sys.executable, "-m", "cirl_study", "serve", str(people), "--out", str(tmp_path / "r")],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert answer.returncode == 2 and answer.stderr.count("\n") == 1
    assert "collect = true" in answer.stderr
    assert not (tmp_path / "r").exists()


def test_a_port_in_use_is_one_line(pipeline_file: Path, tmp_path: Path) -> None:
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        answer = subprocess.run(
            [sys.executable, "-m", "cirl_study", "serve", str(pipeline_file), "--out",
             str(tmp_path / "run"), "--port", str(port)],
            capture_output=True, text=True, timeout=60, env={**os.environ},
        )  # fmt: skip
    assert answer.returncode == 2 and "cannot listen on 127.0.0.1 port" in answer.stderr
