"""``cirl-study serve``'s life: lock the run directory, bind, print the addresses, serve.

The run directory's writer lock (:func:`cirl_study.logs.lock.writer_lock`) is held from before
anything in it is read until the server has stopped, so a second ``serve`` or a ``run`` on the
same directory meanwhile is refused in one line, and the operating system releases it however
the server ends (``kill -9`` included). The socket is bound before the addresses are printed:
a port in use is one line, and ``--port 0`` prints the port the system chose.
"""

from __future__ import annotations

import contextlib
import secrets
import socket
from collections.abc import Callable
from pathlib import Path

import uvicorn

from cirl_study.errors import UserError
from cirl_study.logs.lock import writer_lock
from cirl_study.serve.app import create_app
from cirl_study.serve.experiment import Collecting, Experiment
from cirl_study.study.spec import Pipeline

MAX_CONNECTIONS = 1000
"""Connections served at once; past it a request is answered 503 at once."""

KEEP_ALIVE_SECONDS = 5
"""How long an idle connection is kept open."""


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host`` (a name or an IPv4 or IPv6 address) and ``port``
    (0: one the system chooses).

    Raises:
        UserError: the address cannot be resolved or bound (a port in use), in one line.
    """
    try:
        family, kind, protocol, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except (socket.gaierror, UnicodeError) as error:
        raise UserError(f"--host {host}: cannot resolve it: {error}") from None
    listener = socket.socket(family, kind, protocol)
    try:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(address)
        listener.listen(128)
    except OSError as error:
        listener.close()
        raise UserError(f"cannot listen on {host} port {port}: {error.strerror}") from None
    listener.set_inheritable(True)
    return listener


def address_url(listener: socket.socket) -> str:
    """``http://host:port/`` of a bound ``listener``."""
    host, port = listener.getsockname()[:2]
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/"


def serve(
    pipeline: Pipeline,
    run_dir: Path,
    host: str,
    port: int,
    echo: Callable[[str], None],
) -> None:
    """Serve ``pipeline``'s experiment into ``run_dir`` on ``host``:``port`` until stopped
    (Ctrl-C or a stopping signal), printing through ``echo`` the participants' address and
    the experimenter's status page with its token (new at each start).

    Raises:
        UserError: the pipeline has no experiment, the run directory cannot be made or is
            locked by another writer, its sessions or store are damaged, or the address
            cannot be bound; each in one line, before anything is served.
    """
    spec = Collecting.of(pipeline)
    if run_dir.exists() and not run_dir.is_dir():
        raise UserError(f"{run_dir}: exists and is not a directory")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UserError(f"{run_dir}: cannot create the run directory: {error.strerror}") from None
    with writer_lock(run_dir), contextlib.ExitStack() as stack:
        experiment = Experiment(pipeline, run_dir)
        listener = bind(host, port)
        stack.callback(listener.close)
        token = secrets.token_urlsafe(24)
        url = address_url(listener)
        parameter = spec.experiment.participant_parameter
        echo(f"serving run {pipeline.run_id} into {run_dir}; stop with Ctrl-C")
        if parameter is None:
            echo(f"participants: {url}")
        else:
            echo(f"participants: {url}?{parameter}=<their id> (without it, a random id)")
        echo(f"experimenter: {url}status?key={token}")
        config = uvicorn.Config(
            create_app(experiment, token),
            log_level="warning",
            access_log=False,
            limit_concurrency=MAX_CONNECTIONS,
            timeout_keep_alive=KEEP_ALIVE_SECONDS,
            server_header=False,
            proxy_headers=False,
        )
        uvicorn.Server(config).run(sockets=[listener])
