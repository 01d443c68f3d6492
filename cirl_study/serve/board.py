"""How the page shows a tile game: each character's colour and letter, each task's legend.

Colours are Okabe and Ito's (2008) palette, told apart by readers with every common colour
vision deficiency; each tile also carries its layout character as a letter, so no tile is told
by colour alone. A feature named after a colour takes that colour's entry of the palette
(``orange``, ``purple``, ``cyan`` ...), any other the next entry not yet taken.
"""

from __future__ import annotations

from cirl_study.serve.messages import Board, Meaning, Tile
from cirl_study.study.spec import GameSpec, Task

OKABE_ITO: dict[str, str] = {
    "orange": "#E69F00",
    "sky blue": "#56B4E9",
    "bluish green": "#009E73",
    "yellow": "#F0E442",
    "blue": "#0072B2",
    "vermillion": "#D55E00",
    "reddish purple": "#CC79A7",
}
"""Okabe and Ito's colours, by their names."""

NAMED: dict[str, str] = {
    "orange": "orange",
    "cyan": "sky blue",
    "sky": "sky blue",
    "skyblue": "sky blue",
    "lightblue": "sky blue",
    "green": "bluish green",
    "teal": "bluish green",
    "yellow": "yellow",
    "blue": "blue",
    "red": "vermillion",
    "vermillion": "vermillion",
    "purple": "reddish purple",
    "pink": "reddish purple",
    "magenta": "reddish purple",
}
"""The palette's colour a feature of each of these names takes."""

GREYS = ("#BBBBBB", "#888888", "#555555")
"""Colours past the palette's seven (each still told by its letter)."""

PLAIN = "#FFFFFF"
"""A cell without a feature."""

DARK_TEXT, LIGHT_TEXT = "#000000", "#FFFFFF"


def feature_colours(features: tuple[str, ...]) -> dict[str, str]:
    """Each of ``features`` with its colour (the module docstring).

    >>> feature_colours(("orange", "purple", "cyan"))
    {'orange': '#E69F00', 'purple': '#CC79A7', 'cyan': '#56B4E9'}
    >>> feature_colours(("lava", "orange"))
    {'lava': '#56B4E9', 'orange': '#E69F00'}
    """
    chosen = {name: OKABE_ITO[NAMED[name.lower()]] for name in features if name.lower() in NAMED}
    # Yellow is the goal's, unless the features need it.
    yellow = OKABE_ITO["yellow"]
    free = [colour for colour in OKABE_ITO.values() if colour not in chosen.values()]
    free = [colour for colour in free if colour != yellow] + [yellow] * (yellow in free)
    free += GREYS
    others = [name for name in features if name not in chosen]
    chosen.update(zip(others, free, strict=False))
    return {name: chosen.get(name, GREYS[-1]) for name in features}


def _text_colour(colour: str) -> str:
    """Black or white, whichever reads better on ``colour`` (by its relative luminance)."""
    red, green, blue = (int(colour[i : i + 2], 16) / 255 for i in (1, 3, 5))
    linear = [
        c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in (red, green, blue)
    ]
    luminance = 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]
    return DARK_TEXT if (luminance + 0.05) / 0.05 >= 1.05 / (luminance + 0.05) else LIGHT_TEXT


def board(game: GameSpec) -> Board:
    """The board of the tile game ``game`` (a game with ``[game.tiles]``)."""
    tiles = game.tiles
    if tiles is None:
        raise ValueError("a board is drawn of a tile game")
    legend = dict(tiles.legend)
    names = tuple(name for name in tiles.features.names if name != tiles.step)
    colours = feature_colours(names)
    goal_colour = OKABE_ITO["yellow"] if OKABE_ITO["yellow"] not in colours.values() else PLAIN
    shown: dict[str, Tile] = {}
    for char, feature in legend.items():
        goal = char in tiles.goals
        colour = colours[feature] if feature is not None else goal_colour if goal else PLAIN
        letter = "" if char == "." and feature is None and not goal else char.upper()
        shown[char] = Tile(
            letter=letter,
            colour=colour,
            text_colour=_text_colour(colour),
            feature=feature,
            goal=goal,
        )
    return Board(
        width=game.width,
        height=game.height,
        rows=tiles.layout,
        tiles=shown,
        start=game.start,
        max_moves=game.learning_steps,
        stay=game.demonstrator_stays,
    )


def legend(game: GameSpec, task: Task) -> tuple[tuple[Meaning, ...], float | None]:
    """What each feature of ``game``'s tiles is worth in ``task``, in the order of the game's
    features, and what a move is worth (``None``: the game has no step feature)."""
    tiles = game.tiles
    if tiles is None:
        raise ValueError("a legend is drawn of a tile game")
    weights = dict(zip(tiles.features.names, task.weights, strict=True))
    names = tuple(name for name in tiles.features.names if name != tiles.step)
    colours = feature_colours(names)
    meanings = []
    for name in names:
        weight = weights[name]
        letters = "".join(char.upper() for char, feature in tiles.legend if feature == name)
        kind = "safe" if weight == 0 else "dangerous" if weight < 0 else "good"
        meanings.append(
            Meaning(feature=name, letters=letters, colour=colours[name], weight=weight, kind=kind)
        )
    move = None if tiles.step is None else weights[tiles.step]
    return tuple(meanings), move
