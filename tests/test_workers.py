"""Work shared among worker processes (:mod:`cirl_study.workers`) comes back as in order."""

import os
import time
from pathlib import Path

import pytest

from cirl_study import workers
from cirl_study.errors import UserError
from cirl_study.study.pipeline_file import logged_pipeline


def _square_and_pid(item: int) -> tuple[int, int]:
    return item * item, os.getpid()


def _refuse_odd(item: int) -> int:
    if item % 2:
        raise UserError(f"item {item} is odd")
    return item


def test_results_come_back_in_order_from_other_processes(monkeypatch):
    # Whatever threads other tests left running: this work takes no lock a fork could copy.
    monkeypatch.setattr(workers, "forkable", lambda: True)
    monkeypatch.setattr(workers, "cores", lambda: 2)
    results = list(workers.map_in_workers(_square_and_pid, list(range(40))))
    assert [square for square, _ in results] == [i * i for i in range(40)]
    assert os.getpid() not in {pid for _, pid in results}


def test_one_core_works_in_this_process(monkeypatch):
    monkeypatch.setattr(workers, "cores", lambda: 1)
    results = list(workers.map_in_workers(_square_and_pid, [1, 2, 3]))
    assert results == [(1, os.getpid()), (4, os.getpid()), (9, os.getpid())]


@pytest.mark.parametrize("cores", [1, 2])
def test_the_first_failure_in_order_is_raised_after_the_results_before_it(monkeypatch, cores):
    monkeypatch.setattr(workers, "forkable", lambda: True)
    monkeypatch.setattr(workers, "cores", lambda: cores)
    done = []
    with pytest.raises(UserError, match="item 3 is odd"):
        for result in workers.map_in_workers(_refuse_odd, [0, 2, 4, 3, 6, 5, 8]):
            done.append(result)
    assert done == [0, 2, 4]


def test_a_run_reads_and_validates_the_same_on_two_cores_as_on_one(smoke_run, monkeypatch):
    from cirl_study.logs.reader import read_run
    from cirl_study.logs.validate import validate_run

    monkeypatch.setattr(workers, "cores", lambda: 1)
    alone = read_run(smoke_run, logged_pipeline)
    verdict_alone = validate_run(smoke_run, logged_pipeline)
    monkeypatch.setattr(workers, "forkable", lambda: True)
    monkeypatch.setattr(workers, "cores", lambda: 2)
    shared = read_run(smoke_run, logged_pipeline)
    verdict_shared = validate_run(smoke_run, logged_pipeline)
    assert shared == alone
    assert verdict_shared == verdict_alone


def test_with_another_thread_running_work_stays_in_this_process(monkeypatch):
    import threading

    monkeypatch.setattr(workers, "cores", lambda: 2)
    release = threading.Event()
    other = threading.Thread(target=release.wait)
    other.start()
    try:
        results = list(workers.map_in_workers(_square_and_pid, [1, 2]))
    finally:
        release.set()
        other.join()
    assert results == [(1, os.getpid()), (4, os.getpid())]


def _mark_and_square(item: tuple[str, int]) -> int:
    directory, value = item
    (Path(directory) / f"{value}.began").touch()
    return value * value


def test_started_work_runs_while_this_process_does_its_own(monkeypatch, tmp_path):
    monkeypatch.setattr(workers, "forkable", lambda: True)
    monkeypatch.setattr(workers, "cores", lambda: 2)
    items = [(str(tmp_path), value) for value in range(6)]
    with workers.started(_mark_and_square, items) as results:
        # No result taken yet: the workers have begun on their own.
        deadline = time.monotonic() + 60
        while len(list(tmp_path.glob("*.began"))) < len(items) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(list(tmp_path.glob("*.began"))) == len(items)
        assert list(results) == [value * value for value in range(6)]


def test_calls_of_different_functions_come_back_in_order(monkeypatch):
    monkeypatch.setattr(workers, "forkable", lambda: True)
    monkeypatch.setattr(workers, "cores", lambda: 2)
    calls = [(_square_and_pid, (3,)), (divmod, (17, 5)), (_refuse_odd, (4,)), (max, (2, 9, 4))]
    results = list(workers.map_in_workers(workers.call, calls))
    assert results[0][0] == 9 and results[0][1] != os.getpid()
    assert results[1:] == [(3, 2), 4, 9]


def test_reading_a_run_does_the_callers_own_work_once_meanwhile(smoke_run, monkeypatch):
    from cirl_study.logs.reader import read_run

    monkeypatch.setattr(workers, "forkable", lambda: True)
    monkeypatch.setattr(workers, "cores", lambda: 2)
    calls = []
    contents = read_run(smoke_run, logged_pipeline, meanwhile=lambda: calls.append(len(calls)))
    assert calls == [0]
    assert contents.rows
