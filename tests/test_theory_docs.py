"""The examples of docs/theory.md run and print what the page says."""

from __future__ import annotations

import doctest
import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "theory.md"


def test_every_pycon_example_in_the_theory_page_runs_as_written() -> None:
    text = DOC.read_text()
    blocks = list(re.finditer(r"```pycon\n(.*?)```", text, flags=re.DOTALL))
    assert len(blocks) >= 8
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    shared: dict[str, object] = {}
    for block in blocks:
        line = text.count("\n", 0, block.start(1))
        test = parser.get_doctest(block.group(1), shared, "docs/theory.md", str(DOC), line)
        test.globs = shared  # later blocks use names that earlier ones defined
        runner.run(test, clear_globs=False)
    result = runner.summarize(verbose=False)
    assert result.attempted > 20
    assert result.failed == 0
