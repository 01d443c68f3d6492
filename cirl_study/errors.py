"""User-facing errors.

Every problem a user can cause (a bad pipeline file, a damaged log, an
incomplete design) raises :class:`UserError`. The command line prints its
message as one line and exits with :attr:`UserError.exit_code`; it never
shows a traceback for these.
"""


class UserError(Exception):
    """An error caused by the user's input, reported as a single line."""

    exit_code: int = 2


class RunStopped(UserError):
    """A run stopped before its end for a cause outside its input (a worker died, a cluster
    lost its workers); the message says the cause, the trials kept and how to resume."""

    exit_code: int = 1


class PlayerFault(UserError):
    """A player returned what its contract forbids (:class:`cirl_study.core.players.Human`,
    :class:`~cirl_study.core.players.Robot`): the message names the player, its package and
    the trial."""
