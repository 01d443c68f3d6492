"""The examples of docs/players.md run, in order, and print what the page says."""

from __future__ import annotations

import doctest
import re
from pathlib import Path

from cirl_study.core.players import HUMANS, ROBOTS

DOC = Path(__file__).resolve().parents[1] / "docs" / "players.md"

PAGE_HUMANS = ("greedy", "jumper")
PAGE_ROBOTS = ("contrast", "forgetful")
"""The players the page registers, unregistered after it so that no other test sees them."""


class FencedParser(doctest.DocTestParser):
    """Markdown's code fences read as blank lines: a fence ends an example's output, and the
    page's line numbers stay those of the file."""

    def parse(self, string: str, name: str = "<string>") -> list[str | doctest.Example]:
        return super().parse(re.sub(r"^[ \t]*```.*$", "", string, flags=re.MULTILINE), name)


def test_every_example_of_the_players_page_runs_as_written() -> None:
    try:
        result = doctest.testfile(
            str(DOC),
            module_relative=False,
            parser=FencedParser(),
            optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
        )
    finally:
        for name in PAGE_HUMANS:
            HUMANS.pop(name, None)
        for name in PAGE_ROBOTS:
            ROBOTS.pop(name, None)
    assert result.failed == 0
    assert result.attempted >= 70
