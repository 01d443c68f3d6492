"""Players from installed packages: the ``cirl_study.players`` entry points, loaded on the
first lookup of a name that is not built in (cirl_study.core.players.Registry).

The entry points are faked here; CI installs ``examples/cirl-study-example-players`` and
plays, validates and analyses a pipeline of its players."""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import pytest

from cirl_study.core import players
from cirl_study.core.players import HUMANS, ROBOTS, Human, Robot
from cirl_study.errors import UserError
from cirl_study.study.pipeline_file import parse_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def nobody(*_: object) -> None:
    """A player that never plays: these tests only look it up."""


@dataclass
class FakeEntryPoint:
    name: str
    value: str
    load: Callable[[], object]
    dist: object = field(default_factory=lambda: SimpleNamespace(name="fake-players"))


@pytest.fixture
def installed(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., None]]:
    """Install fake entry points (``install(name=loader, ...)``); forget them after."""
    points: list[FakeEntryPoint] = []

    def install(**loaders: Callable[[], object]) -> None:
        points.extend(FakeEntryPoint(n, f"fake:{n}", load) for n, load in loaders.items())

    def entry_points(group: str) -> list[FakeEntryPoint]:
        return points if group == players.ENTRY_POINTS else []

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.setattr(players, "_INSTALLED", [])
    before = [(registry, dict(dict.items(registry))) for registry in (HUMANS, ROBOTS)]
    yield install
    for registry, players_before in before:
        dict.clear(registry)
        dict.update(registry, players_before)


def test_a_built_in_name_does_not_read_the_installed_packages(installed) -> None:
    installed(shy=lambda: Human(nobody, takes_eta=False))
    assert "expert" in HUMANS and HUMANS.get("expert") is not None and "map" in ROBOTS
    assert players.reference_robot(["posterior_mean", "map"]) == "map"
    assert players._INSTALLED == []


def test_installed_players_are_found_by_name_and_play_in_a_pipeline(installed, tmp_path) -> None:
    installed(shy=lambda: Human(nobody, takes_eta=False), stubborn=lambda: Robot(nobody))
    assert "shy" in HUMANS and isinstance(ROBOTS["stubborn"], Robot)
    assert list(ROBOTS)[-1] == "stubborn" and players.reference_robot(["stubborn", "map"]) == "map"
    text = SMOKE.read_text(encoding="utf-8")
    text = text.replace('humans = ["expert", "best_response"]', 'humans = ["expert", "shy"]')
    text = text.replace('robots = ["map"]', 'robots = ["map", "stubborn"]')
    pipeline = parse_pipeline(text, tmp_path / "mine.toml")
    assert pipeline.main.humans == ("expert", "shy") and pipeline.humans_with_eta == ()


def test_an_unknown_name_lists_the_installed_players_too(installed, tmp_path) -> None:
    installed(shy=lambda: Human(nobody, takes_eta=False))
    text = SMOKE.read_text(encoding="utf-8").replace('"best_response"]', '"bold"]')
    with pytest.raises(UserError, match=r"humans \(expert, .*regret_optimal, .*shy\)"):
        parse_pipeline(text, tmp_path / "mine.toml")


def _fails() -> object:
    raise ImportError("No module named 'missing_dependency'")


@pytest.mark.parametrize(
    ("loader", "message"),
    [
        (_fails, r"the player 'odd' of fake-players \(fake:odd\) cannot be loaded: ImportError"),
        (lambda: "a string", r"the player 'odd' of fake-players \(fake:odd\) is a str, neither"),
    ],
)
def test_a_broken_entry_point_is_one_line_naming_it(installed, loader, message) -> None:
    installed(odd=loader)
    with pytest.raises(UserError, match=message) as error:
        _ = "odd" in HUMANS
    assert "\n" not in str(error.value)


def test_an_installed_player_cannot_take_a_built_in_name(installed) -> None:
    installed(expert=lambda: Human(nobody, takes_eta=False))
    with pytest.raises(UserError, match=r"'expert' of fake-players .*already registered"):
        list(HUMANS)
    assert HUMANS["expert"].takes_eta is False and HUMANS["best_response"].takes_eta
