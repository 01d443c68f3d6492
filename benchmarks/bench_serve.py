"""Load `cirl-study serve`: 50 participants at once, each through every task, and a kill -9.

Usage::

    python benchmarks/bench_serve.py [--participants 50] [--seed 1]

Serves ``pipelines/people-browser.toml`` (8 tasks, two conditions) from a new process
(``python -m cirl_study serve``) into a temporary run directory, then:

1. **Load**: ``--participants`` simulated participants at once (a thread each), each through
   the HTTP API as the page goes: start with a platform id, consent, instructions, practice,
   then every task, each a legal path to the goal drawn from a fixed seed, with the time of
   every move. Every request's response time is taken. The collected store must then hold
   exactly one demonstration per participant and task, each exactly as sent: nothing lost,
   nothing duplicated. Prints the median, p95 and largest response time, of every request
   and of the demonstrations' alone.
2. **Kill -9**: as many new participants start the same way; once a third of their
   demonstrations are acknowledged, the server is killed (SIGKILL) mid-load and started
   again on the same run directory. Each participant comes back with her page's token and
   must resume where the store says she was (no acknowledged demonstration is missing; at
   most the one in flight is stored unacknowledged), then finishes. The store must again
   hold exactly one demonstration per participant and task, each as sent.

Exits non-zero if any check fails.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import random
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from cirl_study.logs.collection import collected
from cirl_study.study.pipeline_file import load_pipeline

PIPELINE = Path(__file__).resolve().parents[1] / "pipelines" / "people-browser.toml"

PATHS = [
    [[0, 2], [1, 2], [2, 2], [3, 2], [4, 2], [5, 2]],
    [[0, 2], [0, 3], [0, 4], [1, 4], [2, 4], [3, 4], [4, 4], [5, 4], [5, 3], [5, 2]],
    [[0, 2], [0, 1], [0, 0], [1, 0], [2, 0], [3, 0], [4, 0], [5, 0], [5, 1], [5, 2]],
    [[0, 2], [1, 2], [1, 3], [2, 3], [3, 3], [4, 3], [5, 3], [5, 2]],
    [[0, 2], [1, 2], [1, 1], [2, 1], [3, 1], [4, 1], [5, 1], [5, 2]],
]
"""Legal demonstrations of the tiles' game: from the start [0, 2] to the goal [5, 2]."""


class ServerGone(Exception):
    """The server did not answer (it was killed)."""


@dataclass
class Participant:
    """One simulated participant: her id, her page's token, what the server acknowledged."""

    participant: str
    rng: random.Random
    token: str | None = None
    acknowledged: dict[str, tuple[list[list[int]], list[float]]] = field(default_factory=dict)


class Client:
    """Requests to the server on ``port``, each one's response time kept."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.times: list[tuple[str, float]] = []
        self.lock = threading.Lock()

    def call(self, method: str, path: str, token: str | None = None, body: object = None) -> dict:
        headers = {"Content-Type": "application/json"}
        if token is not None:
            headers["Authorization"] = f"Bearer {token}"
        data = None if body is None else json.dumps(body).encode()
        began = time.perf_counter()
        connection = http.client.HTTPConnection("127.0.0.1", self.port, timeout=60)
        try:
            connection.request(method, path, body=data, headers=headers)
            response = connection.getresponse()
            payload = response.read()
        except (OSError, http.client.HTTPException) as error:
            raise ServerGone(str(error)) from None
        finally:
            connection.close()
        elapsed = time.perf_counter() - began
        with self.lock:
            self.times.append((path, elapsed))
        answer = json.loads(payload)
        if response.status != 200:
            raise AssertionError(f"{method} {path}: {response.status} {answer}")
        return answer


def walk(client: Client, person: Participant, on_ack: Callable[[], None] = lambda: None) -> None:
    """``person`` through the experiment from wherever she is, to the end."""
    state = client.call(
        "POST", "/api/start", body={"participant": person.participant, "token": person.token}
    )
    if state["token"] is not None:
        person.token = state["token"]
    while state["stage"] != "done":
        stage = state["stage"]
        if stage in ("consent", "instructions"):
            state = client.call("POST", f"/api/{stage}", person.token)
            continue
        path = person.rng.choice(PATHS)
        seconds = [0.0]
        for _ in path[1:]:
            seconds.append(round(seconds[-1] + person.rng.uniform(0.2, 1.5), 3))
        shown = {"task": state["task"]["name"], "path": path, "seconds": seconds}
        if stage == "practice":
            state = client.call("POST", "/api/practice", person.token, shown)
            continue
        state = client.call("POST", "/api/demonstration", person.token, shown)
        person.acknowledged[shown["task"]] = (path, seconds)
        on_ack()


def serve(run: Path, port: int) -> subprocess.Popen[bytes]:
    """``cirl-study serve`` of the pipeline into ``run`` on ``port``, once it answers."""
    process = subprocess.Popen(
        [sys.executable, "-m", "cirl_study", "serve", str(PIPELINE), "--out", str(run),
         "--port", str(port)],
        stdout=subprocess.DEVNULL,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                return process
        except OSError:
            time.sleep(0.05)
    process.kill()
    raise SystemExit("the server did not start")


def check_store(run: Path, people: list[Participant], tasks: int) -> list[str]:
    """What is wrong with the store: every participant's every task, once, as acknowledged."""
    run_id = load_pipeline(PIPELINE).run_id
    stored = collected(run, run_id)
    faults = []
    seen: dict[tuple[str, str], int] = {}
    for shown in stored:
        key = (shown.recorded.participant, shown.task)
        seen[key] = seen.get(key, 0) + 1
    wanted = {person.participant for person in people}
    faults += [f"{key} stored {n} times" for key, n in seen.items() if n != 1]
    faults += [f"{key} of no participant" for key in seen if key[0] not in wanted]
    for person in people:
        mine = {s.task: s for s in stored if s.recorded.participant == person.participant}
        if len(mine) != tasks:
            faults.append(f"{person.participant}: {len(mine)} of {tasks} tasks stored")
        for task, (path, seconds) in person.acknowledged.items():
            shown = mine.get(task)
            if shown is None:
                faults.append(f"{person.participant} {task}: acknowledged, not stored")
            elif [list(c) for c in shown.recorded.path] != path or list(
                shown.recorded.seconds or ()
            ) != seconds:
                faults.append(f"{person.participant} {task}: stored other than sent")
    return faults


def percentile(values: list[float], q: float) -> float:
    return (
        statistics.quantiles(values, n=100, method="inclusive")[q - 1]
        if len(values) > 1
        else values[0]
    )


def report(label: str, times: list[tuple[str, float]]) -> None:
    every = [t for _, t in times]
    shown = [t for path, t in times if path == "/api/demonstration"]
    for what, values in (("every request", every), ("demonstrations", shown)):
        print(
            f"{label}, {what}: {len(values)} requests, median "
            f"{1000 * statistics.median(values):.1f} ms, p95 {1000 * percentile(values, 95):.1f} "
            f"ms, max {1000 * max(values):.1f} ms"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--participants", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    arguments = parser.parse_args()
    count = arguments.participants
    tasks = len(load_pipeline(PIPELINE).tasks or ())
    faults: list[str] = []
    with tempfile.TemporaryDirectory() as directory:
        run = Path(directory) / "run"
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]

        # 1. The load.
        server = serve(run, port)
        client = Client(port)
        people = [
            Participant(f"L{i:03d}", random.Random(arguments.seed * 1000 + i)) for i in range(count)
        ]
        began = time.perf_counter()
        with ThreadPoolExecutor(count) as pool:
            for future in [pool.submit(walk, client, person) for person in people]:
                future.result()
        wall = time.perf_counter() - began
        print(f"load: {count} participants x {tasks} tasks at once in {wall:.1f} s")
        report("load", client.times)
        faults += check_store(run, people, tasks)

        # 2. Kill -9 in the middle of a load, then a restart.
        killed = [
            Participant(f"K{i:03d}", random.Random(arguments.seed * 1000 + count + i))
            for i in range(count)
        ]
        client = Client(port)
        acks = threading.Semaphore(0)
        target = count * tasks // 3
        with ThreadPoolExecutor(count) as pool:
            futures = [pool.submit(walk, client, person, acks.release) for person in killed]
            for _ in range(target):
                acks.acquire()
            server.send_signal(signal.SIGKILL)
            server.wait()
            gone = sum(isinstance(f.exception(), ServerGone) for f in futures)
            unexpected = [
                f.exception()
                for f in futures
                if f.exception() and not isinstance(f.exception(), ServerGone)
            ]
        acknowledged = sum(len(person.acknowledged) for person in killed)
        print(
            f"kill -9 after {acknowledged} acknowledged demonstrations of {count * tasks} "
            f"({gone} participants cut off)"
        )
        faults += [f"unexpected failure: {error}" for error in unexpected]
        stored = {  # what the killed server left durable
            (shown.recorded.participant, shown.task)
            for shown in collected(run, load_pipeline(PIPELINE).run_id)
        }
        server = serve(run, port)
        client = Client(port)
        lost = [(p.participant, task) for p in killed for task in p.acknowledged]
        lost = [key for key in lost if key not in stored]
        faults += [f"lost {key}" for key in lost]
        resumed = 0
        for person in killed:
            asked = {"participant": person.participant, "token": person.token}
            state = client.call("POST", "/api/start", body=asked)
            sent = len(person.acknowledged)
            if sent <= state["done"] <= sent + 1:  # at most the one in flight, unacknowledged
                resumed += 1
            else:
                faults.append(f"{person.participant}: resumed at {state['done']}, sent {sent}")
        print(
            f"after the restart: {len(lost)} acknowledged demonstrations missing; {resumed} of "
            f"{count} participants resumed where the store says"
        )
        with ThreadPoolExecutor(count) as pool:
            for future in [pool.submit(walk, client, person) for person in killed]:
                future.result()
        report("after the restart", client.times)
        faults += check_store(run, people + killed, tasks)
        server.send_signal(signal.SIGTERM)
        server.wait(30)
    for fault in faults[:20]:
        print("FAULT:", fault)
    print("every check passed" if not faults else f"{len(faults)} faults")
    return 1 if faults else 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
