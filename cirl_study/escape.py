"""Text from outside the program, escaped for where it goes.

A run directory may come from someone else: its file names, its logs' provenance and trial
ids can hold anything. A carriage return or an escape sequence printed to a terminal rewrites
what the user reads (a ``FAIL`` line can be made to end in ``OK``), Markdown or HTML in a
report is rendered, a space or a ``;`` in a suggested command splits it or runs another. Every
such string, and every path the user gave, goes out through one of these functions:
:func:`terminal` for a line a terminal shows, :func:`markdown` for a report, :func:`shell` for
an argument of a command the user is told to run.
"""

from __future__ import annotations

import re
import shlex

TERMINAL_LIMIT = 200
"""Characters of one string shown on a terminal before the rest is only counted: a trial id
of a megabyte is named by its start and its length."""

_ESCAPES = {"\t": "\\t", "\n": "\\n", "\r": "\\r"}


def terminal(value: object, limit: int | None = TERMINAL_LIMIT) -> str:
    """``value`` as text a terminal shows as it is, on one line, at most ``limit`` characters
    of it (``None``: all).

    Every character that is not printable (controls, escape sequences, line breaks,
    bidirectional overrides, unpaired surrogates) is shown as its Python escape (``\\r``,
    ``\\x1b``, ``\\u202e``), so it is seen, not obeyed. A longer text keeps its first
    ``limit`` characters and says how long it was. Escaped text is printable, so escaping it
    again (with no limit) changes nothing.

    Examples:
        >>> terminal("trial\\r\\x1b[2KOK")
        'trial\\\\r\\\\x1b[2KOK'
        >>> terminal("x" * 1000, limit=5)
        'xxxxx... (1000 characters)'
    """
    text = str(value)
    if limit is not None and len(text) > limit:
        text = f"{text[:limit]}... ({len(text)} characters)"
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else _escape(ch) for ch in text)


def markdown(value: object) -> str:
    """``value`` as literal Markdown: a code span, the one construct in which neither Markdown
    nor HTML is read (``<img onerror=...>`` shows as those characters).

    Characters that are not printable are shown as by :func:`terminal` (a line break would end
    the span's paragraph, and the text is bounded likewise); the span is fenced by one backtick
    more than the longest run of them in the text, and padded with a space where the text
    starts or ends with a backtick or a space, so the text cannot close it. In a table cell,
    :func:`cirl_study.analysis.report.markdown.table` escapes ``|``.

    Examples:
        >>> markdown("paper"), markdown("a`b")
        ('`paper`', '``a`b``')
    """
    text = terminal(value)
    fence = "`" * (max((len(run) for run in re.findall("`+", text)), default=0) + 1)
    pad = " " if not text or text[0] in "` " or text[-1] in "` " else ""
    return f"{fence}{pad}{text}{pad}{fence}"


def shell(value: object) -> str:
    """``value`` as one shell word: :func:`shlex.quote` (POSIX quoting), or, for a text with
    characters a terminal would not show as they are, bash's ``$'...'`` quoting with each of
    them escaped, so the command printed is both exact and visible. Never shortened: a command
    must be exact.

    Examples:
        >>> shell("cfg/smoke.toml"), shell("my runs/a"), shell("x; touch PWNED")
        ('cfg/smoke.toml', "'my runs/a'", "'x; touch PWNED'")
        >>> shell("a\\rb")
        "$'a\\\\rb'"
    """
    text = str(value)
    if text.isprintable():
        return shlex.quote(text)
    quoted = "".join(
        "\\" + ch if ch in "\\'" else ch if ch.isprintable() else _escape(ch) for ch in text
    )
    return f"$'{quoted}'"


def _escape(character: str) -> str:
    """A character's escape, as Python and bash's ``$'...'`` both read it; an undecodable
    byte of a file name (a surrogate of :data:`os.fsdecode`) as that byte."""
    code = ord(character)
    if character in _ESCAPES:
        return _ESCAPES[character]
    if 0xDC80 <= code <= 0xDCFF:
        return f"\\x{code - 0xDC00:02x}"
    if code < 0x80:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}" if code <= 0xFFFF else f"\\U{code:08x}"
