"""Checks of what a command printed, shared by the test modules."""

from __future__ import annotations


def one_line_error(result, *fragments: str) -> str:
    """The one-line ``error: ...`` message of a command that exited with 2 (a user error),
    holding every one of ``fragments``."""
    assert result.exit_code == 2, result.output
    message = result.output.strip()
    assert message.startswith("error: ") and len(message.splitlines()) == 1, message
    for fragment in fragments:
        assert fragment in message, message
    return message
