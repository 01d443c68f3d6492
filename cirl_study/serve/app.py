"""The experiment over HTTP: a Starlette application of :class:`~cirl_study.serve.experiment.
Experiment`.

Routes (every answer JSON of :mod:`cirl_study.serve.messages` but the pages and their two
files; every path relative, so the experiment runs as well below a reverse proxy's prefix):

* ``GET /``: the participant's page; ``GET /experiment.js``, ``GET /experiment.css``: its
  script and style, fixed files of this package (:data:`PAGE_FILES`): no path of a request
  ever names a file, so nothing outside them is served (``GET /favicon.ico``: none, 204).
* ``GET api/setup``: :class:`~cirl_study.serve.messages.Setup`.
* ``POST api/start`` (:class:`~cirl_study.serve.messages.Start`): a session's
  :class:`~cirl_study.serve.messages.State`, with its token.
* With ``Authorization: Bearer <token>``: ``GET api/state``; ``POST api/consent``, ``POST
  api/instructions``; ``POST api/practice`` and ``POST api/demonstration``
  (:class:`~cirl_study.serve.messages.Submission`).
* The experimenter's, with her token (``?key=`` or ``Authorization: Bearer``): ``GET status``
  (a page) and ``GET api/status`` (:class:`~cirl_study.serve.messages.Status`).

A request's body is read up to :func:`body_limit` bytes and refused past it (413); a body
that is not its type's JSON is refused (400) before anything reads it. Every answer forbids
caching, framing and sniffing, and the page runs only its own script
(``Content-Security-Policy``).
"""

from __future__ import annotations

import hmac
import html
from collections.abc import Awaitable, Callable
from importlib import resources
from typing import Any, TypeVar

import msgspec
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import HTMLResponse, Response
from starlette.routing import Route

from cirl_study.errors import UserError
from cirl_study.serve.experiment import Experiment, Refused
from cirl_study.serve.messages import Problem, Start, Submission

PAGE_FILES: dict[str, str] = {
    "index.html": "text/html; charset=utf-8",
    "experiment.js": "text/javascript; charset=utf-8",
    "experiment.css": "text/css; charset=utf-8",
}
"""The files of the participant's page, in ``cirl_study/serve/page``, with their types."""

HEADERS = {
    "Cache-Control": "no-store",
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    "Content-Security-Policy": (
        "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
        "img-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
}
"""Headers of every answer."""

Body = TypeVar("Body")


def body_limit(max_moves: int) -> int:
    """The largest request body taken: 4 KiB and 64 bytes per cell of the longest path
    (``max_moves + 1`` cells, each two coordinates and a time)."""
    return 4096 + 64 * (max_moves + 1)


def _json(value: Any, status: int = 200) -> Response:
    return Response(msgspec.json.encode(value), status, HEADERS, media_type="application/json")


def _problem(status: int, message: str) -> Response:
    return _json(Problem(error=message), status)


def _bearer(request: Request) -> str | None:
    header = request.headers.get("authorization", "")
    scheme, _, token = header.partition(" ")
    return token.strip() if scheme.lower() == "bearer" and token.strip() else None


def create_app(experiment: Experiment, experimenter_token: str) -> Starlette:
    """The application serving ``experiment``, its status behind ``experimenter_token``."""
    limit = body_limit(experiment.board.max_moves)
    page = {
        name: resources.files("cirl_study.serve").joinpath("page", name).read_bytes()
        for name in PAGE_FILES
    }

    async def body(request: Request, kind: type[Body]) -> Body:
        declared = request.headers.get("content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > limit):
            raise Refused(413, f"the request is larger than {limit} bytes")
        data = bytearray()
        async for chunk in request.stream():
            data += chunk
            if len(data) > limit:
                raise Refused(413, f"the request is larger than {limit} bytes")
        try:
            return msgspec.json.decode(bytes(data), type=kind)
        except msgspec.DecodeError as error:
            raise Refused(400, f"the request is not a {kind.__name__}: {error}") from None

    def token(request: Request) -> str:
        found = _bearer(request)
        if found is None:
            raise Refused(401, "the request has no session token (Authorization: Bearer)")
        return found

    def handled(
        handler: Callable[[Request], Awaitable[Response]],
    ) -> Callable[[Request], Awaitable[Response]]:
        async def respond(request: Request) -> Response:
            try:
                return await handler(request)
            except Refused as refused:
                return _problem(refused.status, refused.message)
            except UserError as error:  # the run directory cannot be written: nothing changed
                return _problem(500, str(error))

        return respond

    def serve_file(name: str) -> Callable[[Request], Awaitable[Response]]:
        async def respond(_request: Request) -> Response:
            return Response(page[name], 200, HEADERS, media_type=PAGE_FILES[name])

        return respond

    async def no_icon(_request: Request) -> Response:
        return Response(b"", 204, HEADERS)

    async def setup(_request: Request) -> Response:
        return _json(experiment.setup())

    async def start(request: Request) -> Response:
        asked = await body(request, Start)
        return _json(await run_in_threadpool(experiment.start, asked.participant, asked.token))

    async def state(request: Request) -> Response:
        return _json(await run_in_threadpool(experiment.state, token(request)))

    async def consent(request: Request) -> Response:
        return _json(await run_in_threadpool(experiment.consent, token(request)))

    async def instructions(request: Request) -> Response:
        return _json(await run_in_threadpool(experiment.instructed, token(request)))

    async def practice(request: Request) -> Response:
        shown = await body(request, Submission)
        return _json(await run_in_threadpool(experiment.practise, token(request), shown))

    async def demonstration(request: Request) -> Response:
        shown = await body(request, Submission)
        return _json(await run_in_threadpool(experiment.submit, token(request), shown))

    def experimenter(request: Request) -> None:
        given = request.query_params.get("key") or _bearer(request) or ""
        if not hmac.compare_digest(given.encode(), experimenter_token.encode()):
            raise Refused(403, "the experimenter's token is missing or wrong")

    async def status(request: Request) -> Response:
        experimenter(request)
        return _json(experiment.status())

    async def status_page(request: Request) -> Response:
        try:
            experimenter(request)
        except Refused as refused:
            return HTMLResponse(html.escape(refused.message), refused.status, HEADERS)
        return HTMLResponse(_status_html(experiment), 200, HEADERS)

    routes = [
        Route("/", serve_file("index.html")),
        Route("/experiment.js", serve_file("experiment.js")),
        Route("/experiment.css", serve_file("experiment.css")),
        Route("/favicon.ico", no_icon),
        Route("/api/setup", handled(setup)),
        Route("/api/start", handled(start), methods=["POST"]),
        Route("/api/state", handled(state)),
        Route("/api/consent", handled(consent), methods=["POST"]),
        Route("/api/instructions", handled(instructions), methods=["POST"]),
        Route("/api/practice", handled(practice), methods=["POST"]),
        Route("/api/demonstration", handled(demonstration), methods=["POST"]),
        Route("/api/status", handled(status)),
        Route("/status", status_page),
    ]
    return Starlette(routes=routes)


def _status_html(experiment: Experiment) -> str:
    """The experimenter's status page: participants started and finished per condition."""
    status = experiment.status()
    rows = "".join(
        f"<tr><td>{html.escape(row.condition)}</td><td>{row.started}</td>"
        f"<td>{row.finished}</td><td>{row.demonstrations}</td></tr>"
        for row in status.conditions
    )
    return (
        '<!doctype html><html lang="en"><head><meta charset="utf-8">'
        '<meta http-equiv="refresh" content="10">'
        f"<title>Status: {html.escape(status.run_id)}</title>"
        '<link rel="stylesheet" href="experiment.css"></head><body><main class="status">'
        f"<h1>Run {html.escape(status.run_id)}</h1>"
        f"<p>{status.participants} participants have started.</p>"
        "<table><thead><tr><th>condition</th><th>started</th><th>finished</th>"
        "<th>demonstrations stored</th></tr></thead>"
        f"<tbody>{rows}</tbody></table></main></body></html>"
    )
