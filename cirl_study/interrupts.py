"""The signals that ask a command to stop: SIGINT (Ctrl-C), SIGTERM and SIGHUP.

Once :func:`install` has run (the command line's entry point, :mod:`cirl_study.__main__`), the
first of them raises :class:`Interrupted` in the main thread, which unwinds the command as
any error does: a run stops its workers and keeps every log file already complete
(:mod:`cirl_study.study.runner`), and the command line prints one line
(:func:`report`) and exits with 128 + the signal's number, as a shell reports a process a
signal ended. Any later one of them ends the process at once (:func:`os._exit`): after
that line (printed then, if it was not yet), and after killing the worker processes this
process started. The operating system releases the run directory's lock as the process
ends (no worker holds a copy of it: :mod:`cirl_study.logs.lock`), and nothing left to
unwind can print a traceback.

A process forked from this one is a worker: the handler does nothing there, and a worker
ignores the three signals outright once it calls :func:`leave_to_parent`. A terminal's Ctrl-C
or hang-up reaches its whole process group, and it is the main process that stops the
workers and reports, once. A signal the process was started with ignored (``nohup``, a
shell's background job) stays ignored.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from types import FrameType

STOPPING: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
"""The signals that stop a command."""


class Interrupted(KeyboardInterrupt):
    """A signal of :data:`STOPPING` stopped the command; ``detail`` says what was kept.

    A :class:`KeyboardInterrupt`, so that whatever stops cleanly on Ctrl-C (a pool, a
    progress bar) stops on SIGTERM and SIGHUP alike, and no ``except Exception`` swallows it.
    """

    def __init__(self, signum: int = signal.SIGINT, detail: str = "") -> None:
        super().__init__(signum, detail)
        self.signum = signum
        self.detail = detail

    @classmethod
    def of(cls, interrupt: KeyboardInterrupt, detail: str = "") -> Interrupted:
        """``interrupt`` (a plain :class:`KeyboardInterrupt` is a SIGINT's) with ``detail``."""
        return cls(getattr(interrupt, "signum", signal.SIGINT), detail)

    @property
    def exit_code(self) -> int:
        """128 + the signal's number."""
        return 128 + self.signum

    def line(self) -> str:
        """``interrupted (SIGTERM)``, then ``: <detail>`` if there is one."""
        head = f"interrupted ({signal.Signals(self.signum).name})"
        return f"{head}: {self.detail}" if self.detail else head


_owner: int | None = None
"""The process that installed the handler: the only one it acts in."""
_first: int | None = None
"""The first stopping signal received, once one is."""
_reported = False
"""Whether the line of the interruption is printed."""
_held: list[int] | None = None
"""While the main thread is in a :func:`deferred` block: the signal held back, if one came."""


def install() -> None:
    """Handle :data:`STOPPING` in this process as the module's docstring says (main thread
    only).

    Python ignores an exception raised where nothing can catch it (an at-fork hook, a
    finalizer), after printing it: :class:`Interrupted` raised there is not printed, and its
    signal is sent again a moment later (:func:`sys.unraisablehook`), so that no signal is
    lost.
    """
    global _owner
    _owner = os.getpid()
    for signum in STOPPING:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            signal.signal(signum, _handle)
    sys.unraisablehook = _raise_again(sys.unraisablehook)


def _raise_again(
    hook: Callable[[sys.UnraisableHookArgs], object],
) -> Callable[[sys.UnraisableHookArgs], object]:
    """``hook``, but for an :class:`Interrupted` that Python ignored: its signal again."""

    def unraisable(unraisable: sys.UnraisableHookArgs) -> object:
        global _first
        interrupt = unraisable.exc_value
        if not isinstance(interrupt, Interrupted) or os.getpid() != _owner:
            return hook(unraisable)
        _first = None
        # From another thread, a moment later: sent from here, it would be handled here.
        threading.Timer(0.01, os.kill, (os.getpid(), interrupt.signum)).start()
        return None

    return unraisable


def leave_to_parent(parent: int | None = None) -> None:
    """Ignore :data:`STOPPING` in this worker process: its parent stops it.

    With ``parent`` (the parent's process id, read before the fork; called in the worker
    right after it), the worker also ends when that parent does, whatever the parent died of
    (SIGKILL leaves it no chance to stop its workers) and whatever the worker is computing:

    * on Linux the kernel kills it (:func:`end_with_parent`: ``PR_SET_PDEATHSIG`` with
      SIGKILL), at once, even inside a compiled kernel that holds the GIL;
    * where that is not available (macOS, the BSDs), a daemon thread polls the parent
      (:data:`PARENT_POLL_SECONDS`) and ends the worker within that time whenever the
      worker runs Python code or a kernel that releases the GIL; a worker inside a compiled
      kernel that holds the GIL ends when the kernel returns.

    A worker whose parent is already gone when it gets here ends at once.
    """
    for signum in STOPPING:
        signal.signal(signum, signal.SIG_IGN)
    if parent is not None:
        end_with_parent(parent)
        threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()


PR_SET_PDEATHSIG = 1
"""The ``prctl`` option that names the signal a process gets when its parent ends
(``<linux/prctl.h>``)."""


def end_with_parent(parent: int) -> bool:
    """Have the kernel SIGKILL this process when its parent ``parent`` ends (Linux's
    ``prctl(PR_SET_PDEATHSIG, SIGKILL)``); end at once if ``parent`` is no longer its parent
    (it ended between the fork and the call). Whether the kernel will.

    The signal comes when the *thread* that forked this process ends: callers fork from the
    main thread (:mod:`cirl_study.workers` forks only with no other thread running,
    :class:`cirl_study.study.engines.LocalEngine` before the run starts any), whose end is
    the process's.
    """
    armed = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent:  # the parent ended before the kernel was told to watch it
        os._exit(1)
    return armed


PARENT_POLL_SECONDS = 0.5
"""How often a worker looks whether its parent is gone."""


def _exit_with_parent(parent: int) -> None:
    """Poll until the process ``parent`` is no longer this one's parent, then end at once."""
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_SECONDS)
    os._exit(1)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold back the first of :data:`STOPPING` until the block ends, when it acts; a second
    one still ends the process at once.

    For a short step that must be whole or not at all: a batch's log file renamed into place
    and its trials counted as kept; workers forked and recorded as the pool's, so that each
    one is stopped. Held back both from this thread (its signal mask, which a process forked
    here starts with too) and, in the main thread, from the handler :func:`install` sets,
    which runs there whichever thread the signal reached.
    """
    global _held
    outermost = threading.current_thread() is threading.main_thread() and _held is None
    if outermost:
        _held = []
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, STOPPING)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        if outermost:
            held, _held = _held, None
            if held:
                raise Interrupted(held[0])


def report(interrupt: KeyboardInterrupt) -> int:
    """Print ``interrupt``'s line on stderr, unless a line was printed already; its exit code."""
    global _reported
    stopped = interrupt if isinstance(interrupt, Interrupted) else Interrupted.of(interrupt)
    if not _reported:
        _reported = True
        print(stopped.line(), file=sys.stderr, flush=True)
    return stopped.exit_code


def _handle(signum: int, frame: FrameType | None) -> None:
    global _first, _reported
    if os.getpid() != _owner:
        return  # a forked worker, before it ignores the signal itself
    if _first is None:
        _first = signum
        if _held is not None:
            _held.append(signum)  # raised as the deferred block ends
            return
        raise Interrupted(signum)
    stopped = Interrupted(_first)
    if not _reported:
        _reported = True
        # Straight to the descriptor: the signal may have come in the middle of a write to
        # sys.stderr. At a terminal, a live progress bar hid the cursor and holds the line.
        terminal = "\x1b[?25h\n" if os.isatty(2) else ""
        os.write(2, f"{terminal}{stopped.line()}\n".encode())
    with contextlib.suppress(Exception):
        for child in multiprocessing.active_children():
            child.kill()
    os._exit(stopped.exit_code)
