"""User-facing errors.

Every problem a user can cause (a bad pipeline file, a damaged log, an
incomplete design) raises :class:`UserError`. The command line prints its
message as one line and exits with :attr:`UserError.exit_code`; it never
shows a traceback for these.
"""


class UserError(Exception):
    """An error caused by the user's input, reported as a single line."""

    exit_code: int = 2
