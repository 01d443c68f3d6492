"""Players from installed packages: the ``cirl_study.players`` entry points, loaded on the
first lookup of a name that is not built in (cirl_study.core.players.Registry).

The entry points are faked here; CI installs ``examples/cirl-study-example-players`` and
plays, validates and analyses a pipeline of its players."""

from __future__ import annotations

import importlib.metadata
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.core import players
from cirl_study.core.players import HUMANS, ROBOTS, Human, Robot
from cirl_study.errors import UserError
from cirl_study.logs.reader import read_run
from cirl_study.study.pipeline_file import logged_pipeline, parse_pipeline
from cirl_study.study.plan import study_trials

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def nobody(*_: object) -> None:
    """A player that never plays: these tests only look it up."""


@dataclass
class FakeEntryPoint:
    name: str
    value: str
    load: Callable[[], object]
    dist: object = field(
        default_factory=lambda: SimpleNamespace(name="fake-players", version="0.1")
    )


@pytest.fixture
def installed(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., None]]:
    """Install fake entry points (``install(name=loader, ...)``); forget them after."""
    points: list[FakeEntryPoint] = []

    def install(**loaders: Callable[[], object]) -> None:
        points.extend(FakeEntryPoint(n, f"fake:{n}", load) for n, load in loaders.items())

    real = importlib.metadata.entry_points

    def entry_points(group: str | None = None, **selection: str) -> object:
        if group == players.ENTRY_POINTS:
            return points
        return real(**selection) if group is None else real(group=group, **selection)

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.setattr(players, "_INSTALLED", [])
    packages = dict(players.PACKAGES)
    players.PACKAGES.clear()
    before = [(registry, dict(dict.items(registry))) for registry in (HUMANS, ROBOTS)]
    yield install
    players.PACKAGES.clear()
    players.PACKAGES.update(packages)
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


def test_a_player_breaking_its_contract_stops_the_run_in_one_line_keeping_its_trials(
    installed, tmp_path
) -> None:
    """A human that shows a jump on one subject's trials: the run ends in one line naming
    the human, its package and the trial, the trials logged before stay logged, and the run
    resumes once the human is mended."""
    target = {}

    def jumps_on_one_subject(game, theta, eta, seeds):
        from cirl_study.core.humans import expert_paths

        paths = expert_paths(game.learning, theta)
        jumping = seeds == target["seed"]
        paths[jumping, 2] = paths[jumping, 0] + 2 * game.learning.phase.horizon
        return paths

    installed(jumpy=lambda: Human(jumps_on_one_subject, takes_eta=False))
    text = SMOKE.read_text(encoding="utf-8")
    text = text.replace('humans = ["expert", "best_response"]', 'humans = ["expert", "jumpy"]')
    pipeline = parse_pipeline(text, tmp_path / "mine.toml")
    planned = study_trials(pipeline, {})
    jumpy = [trial for trial in planned if trial.human == "jumpy"]
    target["seed"] = jumpy[-1].seed
    (tmp_path / "mine.toml").write_text(text, encoding="utf-8")
    run = tmp_path / "run"
    command = ["run", str(tmp_path / "mine.toml"), "--out", str(run), "--workers", "1"]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 2, result.output
    line = result.output.strip().splitlines()[-1]
    assert line.startswith(
        "error: human 'jumpy' (package fake-players 0.1) showed a demonstration that is not a "
        f"path of the game in trial {jumpy[-1].trial_id}: "
    ), line
    kept = int(line.split("; ")[-2].split()[0])
    logged = read_run(run, logged_pipeline, salvage=True).rows
    assert 0 < kept < len(planned) and len(logged) == kept
    target["seed"] = -1  # the player mended: the run resumes, keeping what it logged
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    assert f"{kept} were already logged" in result.output


@pytest.mark.parametrize("name", ["odd:one", "a=b", "x@y", "with space", "", "9lives", "é"])
def test_a_player_name_that_would_break_an_id_is_refused_in_one_line(installed, name) -> None:
    installed(**{name: lambda: Human(nobody, takes_eta=False)})
    with pytest.raises(UserError, match=r"is not a name for a human: a letter or _") as error:
        _ = "shy" in HUMANS
    assert "\n" not in str(error.value) and "fake-players" in str(error.value)


def test_a_player_no_longer_installed_is_named_with_its_package(
    installed, tmp_path, monkeypatch
) -> None:
    """Provenance records the package each installed player came from; once it is
    uninstalled, ``validate`` and ``analyze`` say so in those words, not as a damaged log."""
    from cirl_study.core.humans import expert_paths

    def copies_the_expert(game, theta, eta, seeds):
        return expert_paths(game.learning, theta)

    installed(copycat=lambda: Human(copies_the_expert, takes_eta=False))
    text = SMOKE.read_text(encoding="utf-8")
    text = text.replace('humans = ["expert", "best_response"]', 'humans = ["expert", "copycat"]')
    (tmp_path / "mine.toml").write_text(text, encoding="utf-8")
    run = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", str(tmp_path / "mine.toml"), "--out", str(run)])
    assert result.exit_code == 0, result.output
    provenance = read_run(run, logged_pipeline).provenance[0]
    assert json.loads(provenance["players"]) == {"copycat": "fake-players 0.1"}

    # Uninstalled: no entry point any more, and nothing of it registered.
    real = importlib.metadata.entry_points
    monkeypatch.setattr(
        importlib.metadata,
        "entry_points",
        lambda group=None, **s: [] if group == players.ENTRY_POINTS else real(**s),
    )
    dict.pop(HUMANS, "copycat")
    players._INSTALLED.clear()
    players.PACKAGES.clear()
    said = "human 'copycat' is not installed; it came from package fake-players 0.1"
    result = CliRunner().invoke(app, ["validate", str(run)])
    assert result.exit_code == 1
    assert all(said in line for line in result.stdout.splitlines()[:-1]), result.stdout
    result = CliRunner().invoke(app, ["analyze", str(run)])
    assert result.exit_code == 2 and said in result.stderr and result.stderr.count("\n") == 1
