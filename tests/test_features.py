"""Feature kinds (:mod:`cirl_study.features`): the matrix of each kind, the rules of a tile
layout, and the registry that a record's ``features`` decodes by."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.features import (
    FEATURE_KINDS,
    Features,
    RBFFeatures,
    TileFeatures,
    feature_matrix,
)
from cirl_study.record import TrialSpec

HO_LAYOUT = (".oooo.", ".oppp.", ".opccy", ".oppc.", ".cccc.")
"""The coloured-tile task of Ho et al. (2016), rows from y = 4 down to y = 0."""

HO_TILES = TileFeatures(
    layout=HO_LAYOUT,
    names=("orange", "purple", "cyan", "step"),
    legend=(("o", "orange"), ("p", "purple"), ("c", "cyan"), (".", None), ("y", None)),
    step="step",
)


def test_the_tiles_of_ho_et_al_are_the_hand_written_matrix() -> None:
    o, p, c, w = (1, 0, 0, 1), (0, 1, 0, 1), (0, 0, 1, 1), (0, 0, 0, 1)
    rows_by_y = {
        4: [w, o, o, o, o, w],
        3: [w, o, p, p, p, w],
        2: [w, o, p, c, c, w],  # the goal (5, 2) has only the per-move feature
        1: [w, o, p, p, c, w],
        0: [w, c, c, c, c, w],
    }
    want = np.array([rows_by_y[y][x] for y in range(5) for x in range(6)], dtype=float)
    np.testing.assert_array_equal(feature_matrix(6, 5, HO_TILES), want)
    assert HO_TILES.cells_of("y", 6, 5) == ((5, 2),)
    assert HO_TILES.faults(6, 5) == []


def test_the_rbf_matrix_is_the_definition() -> None:
    features = RBFFeatures(centers=((1.0, 2.0), (0.5, 0.0)), sigma=1.5)
    cells = [(x, y) for y in range(3) for x in range(4)]
    want = [
        [np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * 1.5**2)) for cx, cy in features.centers]
        for x, y in cells
    ]
    np.testing.assert_allclose(feature_matrix(4, 3, features), want, rtol=1e-15)


@pytest.mark.parametrize(
    ("change", "fault"),
    [
        ({"layout": (".oooo.", ".opp.")}, "the layout has 2 rows of [5, 6] characters"),
        ({"layout": (".oooo.",) * 4 + (".oooz.",)}, "the layout's characters ['z']"),
        ({"names": ("orange", "orange", "cyan", "step")}, "a feature is named twice"),
        ({"names": ("orange", "purple", "step")}, "not the names"),
        ({"step": "cyan"}, "the step feature 'cyan' is also a tile's"),
        (
            {"legend": (("o", "orange"), ("o", "purple"), ("c", "cyan"), (".", None))},
            "the legend names a character twice",
        ),
    ],
)
def test_each_fault_of_a_tile_layout_is_named(change: dict, fault: str) -> None:
    tiles = msgspec.structs.replace(HO_TILES, **change)
    assert any(fault in found for found in tiles.faults(6, 5)), tiles.faults(6, 5)


@st.composite
def tile_games(draw) -> tuple[TileFeatures, int, int]:
    width, height = draw(st.integers(1, 7)), draw(st.integers(1, 6))
    symbols = draw(st.lists(st.sampled_from("abcdefg.#"), min_size=1, max_size=5, unique=True))
    named = {s: draw(st.sampled_from([None, f"f{s}" if s.isalpha() else "dot"])) for s in symbols}
    layout = tuple(
        "".join(draw(st.sampled_from(symbols)) for _ in range(width)) for _ in range(height)
    )
    step = draw(st.sampled_from([None, "step"]))
    names = sorted({n for n in named.values() if n is not None} | ({step} if step else set()))
    if not names:
        names, step = ["step"], "step"
    names = draw(st.permutations(names))
    legend = tuple(sorted(named.items()))
    return TileFeatures(layout=layout, names=tuple(names), legend=legend, step=step), width, height


@given(game=tile_games())
@settings(max_examples=80, deadline=None)
def test_a_sound_tile_matrix_is_one_hot_plus_the_step(game) -> None:
    tiles, width, height = game
    assert tiles.faults(width, height) == []
    phi = feature_matrix(width, height, tiles)
    assert phi.shape == (width * height, len(tiles.names))
    legend = dict(tiles.legend)
    for y in range(height):
        for x in range(width):
            row = phi[y * width + x]
            name = legend[tiles.layout[height - 1 - y][x]]
            want = [
                1.0 if feature == name or feature == tiles.step else 0.0 for feature in tiles.names
            ]
            assert row.tolist() == want


def test_every_registered_kind_is_a_member_of_the_records_union() -> None:
    assert set(Features.__args__) == set(FEATURE_KINDS)
    tags = [kind.__struct_config__.tag for kind in FEATURE_KINDS]
    assert tags == [kind.kind for kind in FEATURE_KINDS]
    assert len(set(tags)) == len(tags)


def test_a_new_kind_is_one_class_and_one_registry_entry(tmp_path) -> None:
    """A test-only kind, a checkerboard, in a module of its own: registered by one entry of
    ``FEATURE_KINDS`` (before the record types are built), a trial of it plays, and its record
    survives the JSON round trip and the record checks."""
    module = tmp_path / "checker_kind.py"
    module.write_text(
        textwrap.dedent(
            '''
            from typing import ClassVar
            import msgspec, numpy as np

            class CheckerFeatures(msgspec.Struct, tag="checker", tag_field="kind", frozen=True,
                                  kw_only=True):
                """Two features: the black cells and the white ones of a checkerboard."""
                kind: ClassVar[str] = "checker"
                count: ClassVar[int] = 2

                def faults(self, width, height):
                    return []

                def matrix(self, width, height, exp):
                    ys, xs = np.divmod(np.arange(width * height), width)
                    black = ((xs + ys) % 2 == 0).astype(float)
                    return np.stack([black, 1.0 - black], axis=1)
            '''
        )
    )
    script = textwrap.dedent(
        """
        import typing, cirl_study.features as features
        from checker_kind import CheckerFeatures
        features.FEATURE_KINDS += (CheckerFeatures,)          # the registry entry
        features.Features = typing.Union[features.FEATURE_KINDS]
        from cirl_study import record
        from cirl_study.core.trial import play_trials
        from cirl_study.logs.record_checks import record_faults
        spec = record.TrialSpec(trial_id="t", run_id="r", block="main", subject="s",
            human="expert", robot="map", num_features=2, rationality=1.0, eta=None, seed=1,
            grid=record.Grid(width=3, height=3), start=(1, 1), learning_steps=2,
            deployment_steps=2, features=CheckerFeatures(), theta=(0.5, -0.5))
        played = play_trials([spec])[0]
        again = record.decode(record.encode(played))
        assert again == played and record_faults(again) == [], record_faults(again)
        print(again.features.kind, [list(cell) for cell in again.demonstration.states])
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
        check=False,
    )
    assert done.returncode == 0, done.stderr
    kind, path = done.stdout.split(" ", 1)
    assert kind == "checker"
    assert path.strip() == "[[1, 1], [1, 1], [1, 1]]"  # only (1, 1) is black within reach


def test_a_trial_spec_decodes_each_kind_by_its_tag() -> None:
    for features in (HO_TILES, RBFFeatures(centers=((0.0, 0.0),), sigma=1.0)):
        data = msgspec.json.encode({"features": features})
        assert b'"kind":"' + features.kind.encode() + b'"' in data
        decoded = msgspec.json.decode(data, type=dict[str, Features])
        assert decoded["features"] == features
    assert "features" in TrialSpec.__struct_fields__
