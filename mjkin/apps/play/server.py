"""``mjkin play``'s HTTP server: the page, a small JSON API, single JPEG frames and an MJPEG stream.

A Starlette app on uvicorn's h11 protocol. Routes (JSON in and out):

- ``GET /`` the page; ``GET /info`` methods, goal kinds, frames, joint sliders, image size.
- ``GET /state`` → ``{"model", "q", "targets": {frame: [x, y, z, qw, qx, qy, qz]}, "error": [pos, rot],
  "iterations", "method", ...}`` (also ``goal``, ``status``, ``success``, ``singular_values``,
  ``manipulability``, ``step``, ``recording``, ``unsaved`` (a stopped recording not yet written), ``save`` (the
  last take's writing, see ``POST /stop``, or null), ``screen``:
  each target's image point ``[u, v]``, ``camera``: ``{"lookat", "distance", "azimuth", "elevation"}``).
- ``POST /target`` ``{"frame", "pos": [x, y, z], "quat"?: [w, x, y, z]}`` → the solve runs, the new state.
- ``POST /drag`` ``{"frame", "uv": [u, v]}`` (image fractions, top-left origin), ``{"frame", "depth": m}``
  (along the line of sight) or ``{"frame", "turn": rad}`` (about it, for pose goals).
- ``POST /view`` ``{"orbit": [d_azimuth, d_elevation]}`` (degrees, about the look-at point), ``{"zoom": factor}``
  (the distance times it; below 1: closer) or ``{"reset": true}`` (the initial camera); later drags use the new view.
- ``POST /method`` ``{"method"}``, ``/goal`` ``{"goal"}``, ``/frames`` ``{"frames": [...]}``,
  ``/joint`` ``{"joint", "value"}``, ``/step`` ``{"on": bool}``, ``/reset`` ``{}``.
- ``POST /constraints`` ``{"clearance"?: bool, "balance"?: bool, "max_joint_speed"?: rad/s | null}``: hard
  constraints in every solve (a ``Clearance(0)``; the CoM over the feet; a ``StepLimit`` of the speed over the
  frame rate, the figure moving toward a far target frame by frame); ``/state`` reports them (``clearance``,
  ``balance``, ``max_joint_speed``), the closest pair (``closest``: ``{"geoms", "distance", "a", "b"}``, witness
  points) and the support (``support``: ``{"polygon", "com", "inside"}``), both drawn in the frames.
- ``POST /solutions`` ``{}``: every IK solution of the one active frame's target (:func:`mjkin.solutions`, at most
  16), the first shown → ``{"count", "index", ...state}``; ``{"next": true}`` or ``{"index": i}`` shows another
  (cyclically); ``/state`` reports ``solutions``: ``{"count", "index"}`` until the target changes.
- ``POST /record`` ``{}`` starts recording (journaled, see :mod:`mjkin.apps.play.journal`); ``POST /stop`` ``{}`` starts
  writing the script and the mp4 (into the folder checked writable at the start) and returns at once →
  ``{"path", "video", "frames", "progress": 0..1, "done", "error"}``, which ``/state`` reports as ``save``
  until ``done`` (both files written) or ``error`` (one line).
- ``GET /frame.jpg`` the current frame (waits until it shows the current state);
  ``GET /stream.mjpg`` every new frame (``multipart/x-mixed-replace``, parts split by :data:`PART`).

A bad request is a 400 with ``{"error": "one line"}``; a change while another client
holds control is a 409 (see :mod:`mjkin.apps.play.session`); a recording whose journal cannot be made is a 500,
one that cannot be written is kept (``save.error`` says why; ``POST /stop`` again writes it). Every reply is
strict JSON: a number that is not finite (an image point of a target level with the camera, say) is sent as
``null``.

The door, as Jupyter's: every request, the page included, carries the token made at the
start (:attr:`PlayServer.url` has it as ``?token=``; the API also takes it as the header
``X-Mjkin-Token: T`` or ``Authorization: token T``), else 403. The ``Host`` header must
name the bound address, ``localhost``, ``127.0.0.1`` or ``[::1]`` with the port, else 421
(a page that rebinds its own name to this machine is not served). A POST whose ``Origin``
is not the page's own is a 403, one whose body is not ``application/json`` a 415 (a browser
sends neither cross-origin without a preflight) and preflights (``OPTIONS``) are refused.

The connection rules are uvicorn's and h11's: strict HTTP/1.1 framing (a bad
``Content-Length`` is a 400; a chunked body is decoded; a POST with neither is a 411 here),
a listen backlog of :data:`BACKLOG`, and the blocking work (solves, snapshots, frames) in anyio's
bounded thread pool; and this module's (:class:`Gate`): at most :data:`MAX_CONNECTIONS` connections
that have shown the token (a request with it on one more is a 503; connections without it do not
count, so anyone on the machine holding sockets open cannot lock the page out), a new connection
closed unless it completes its first request head within :data:`HEAD_TIMEOUT` seconds, and idle
ones after :data:`IDLE_TIMEOUT` seconds.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import json
import os
import secrets
import signal
import socket
import sys
import threading
import webbrowser
from collections.abc import AsyncIterator, Awaitable, Callable
from importlib.resources import files
from pathlib import Path
from types import FrameType
from typing import Any, ClassVar
from urllib.parse import parse_qs

from ...errors import InputError, MjkinError, MjkinIOError
from ...kinematics.tree import Tree, load, source_of
from ...runtime.files import strict_json
from . import NEEDS_PLAY_EXTRA, core, journal
from .session import Busy, Playground, recordings_folder

try:  # the play extra: without it, one line saying what to install (mjkin play's exit status 2)
    import uvicorn
    from starlette.applications import Starlette
    from starlette.concurrency import run_in_threadpool
    from starlette.datastructures import Headers
    from starlette.requests import ClientDisconnect, Request
    from starlette.responses import PlainTextResponse, Response, StreamingResponse
    from starlette.routing import Route
    from starlette.types import ASGIApp, Receive, Scope, Send
    from uvicorn.protocols.http.h11_impl import H11Protocol
except ModuleNotFoundError as missing:
    raise MjkinError(NEEDS_PLAY_EXTRA.format(missing=missing.name)) from None

MAX_BODY = 1 << 16
BOUNDARY = "mjkin-play-frame"
PART = f"\r\n--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n\r\n".encode()  # ends one image, starts the next
BACKLOG = 1024  # connections the kernel queues before the server accepts them
MAX_CONNECTIONS = 64  # open connections that have shown the token (a page keeps 2-3); one more is a 503
HEAD_TIMEOUT = 1.0  # seconds a new connection has to complete its first request head, else it is closed
IDLE_TIMEOUT = 5  # seconds a connection may wait between requests, or for a later one to be complete
BODY_TIMEOUT = 10.0  # seconds a request body may take to arrive
SHUTDOWN_TIMEOUT = 5  # seconds the server waits for requests in progress when it stops
NO_STORE = {"Cache-Control": "no-store"}
CLOSE = {**NO_STORE, "Connection": "close"}  # refusals: the body may be unread, so the connection ends
PAGE_REFUSED = "403 Forbidden: open the playground at the address mjkin play printed (it ends in ?token=...)"
TOKEN_HEADER = "x-mjkin-token"
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "[::1]")


class Refused(Exception):
    """A request turned away before its route runs: an HTTP status and one line."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def one_line(message: str) -> str:
    """``message`` on one line."""
    return " ".join(str(message).split())


def reply(doc: object, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    """A strict-JSON reply."""
    return Response(strict_json(doc), status, headers or NO_STORE, media_type="application/json")


def error(status: int, message: str, headers: dict[str, str] | None = None) -> Response:
    """``{"error": "one line"}`` with ``status``."""
    return reply({"error": one_line(message)}, status, headers)


# ------------------------------------------------------------------ the door
def host_names(host: str, port: int, bound: str) -> frozenset[str]:
    """The ``Host`` values this server answers: its address (as given and as bound) or loopback, with the port."""
    def literal(name: str) -> str:
        return f"[{name}]" if ":" in name and not name.startswith("[") else name

    names = {literal(n).lower() for n in (host, bound, *LOOPBACK_NAMES)}
    return frozenset({f"{n}:{port}" for n in names} | (names if port == 80 else set()))


def tokens_given(headers: Headers, query: bytes) -> list[str]:
    """The tokens a request carries: ``X-Mjkin-Token``, ``Authorization: token T``, ``?token=``."""
    given = [headers.get(TOKEN_HEADER, "")]
    scheme, _, value = headers.get("authorization", "").partition(" ")
    if scheme.lower() == "token":
        given.append(value.strip())
    given += parse_qs(query.decode("latin-1")).get("token", [])
    return [t for t in given if t]


def has_token(scope: Scope, token: str) -> bool:
    """The request ``scope`` carries ``token`` (compared in constant time)."""
    given = tokens_given(Headers(scope=scope), scope["query_string"])
    return any(hmac.compare_digest(t.encode(), token.encode()) for t in given)


def check_request(scope: Scope, token: str, hosts: frozenset[str]) -> None:
    """Turn away what the door does not let in (see the module docstring).

    Raises:
        Refused: 421 for a foreign ``Host``, 403 for a preflight, a missing or wrong token or a
            foreign ``Origin``, 415 for a POST body that is not JSON.
    """
    headers = Headers(scope=scope)
    host = headers.get("host", "").lower()
    if host not in hosts:
        raise Refused(421, f"Host {host or 'none'!r} is not this server's: use the URL mjkin play printed (the address "
                           "it serves on, or localhost, 127.0.0.1 or [::1], with its port)")
    method = scope["method"]
    if method == "OPTIONS":
        raise Refused(403, "cross-origin requests are refused: the playground answers its own page only")
    if not has_token(scope, token):
        raise Refused(403, PAGE_REFUSED if scope["path"] in ("/", "/index.html") else
                      "a missing or wrong token: send the one in the URL mjkin play printed, as ?token=..., "
                      "the header X-Mjkin-Token or Authorization: token ...")
    if method == "POST":
        origin = headers.get("origin")
        if origin is not None and origin.lower() != f"http://{host}":
            raise Refused(403, f"a change from another origin ({origin}) is refused; use the playground's page")
        kind = headers.get("content-type", "").split(";", 1)[0].strip().lower()
        if kind != "application/json":
            raise Refused(415, f"a POST body must be Content-Type: application/json, got {kind or 'none'}")


class Door:
    """ASGI middleware: :func:`check_request` before every request; a refusal is one line (JSON, text for the page)."""

    def __init__(self, app: ASGIApp, token: str, hosts: frozenset[str]) -> None:
        self.app, self.token, self.hosts = app, token, hosts

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Check, then pass the request on."""
        if scope["type"] == "http":
            try:
                check_request(scope, self.token, self.hosts)
            except Refused as e:
                page = scope["path"] in ("/", "/index.html")
                response = PlainTextResponse(f"{e}\n", e.status, CLOSE) if page else error(e.status, str(e), CLOSE)
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


# ------------------------------------------------------------- request bodies
async def read_json(request: Request) -> dict:
    """The JSON object of a POST body (empty: ``{}``), at most :data:`MAX_BODY` bytes within :data:`BODY_TIMEOUT`.

    Raises:
        Refused: 411 without a length (neither ``Content-Length`` nor chunked), 413 too large,
            408 too slow, 400 cut off.
        InputError: not a JSON object (too deeply nested included).
    """
    length = request.headers.get("content-length")
    if length is None and "transfer-encoding" not in request.headers:
        raise Refused(411, "a POST needs a Content-Length (or a chunked body)")
    if length is not None and int(length) > MAX_BODY:  # h11 let only digits through
        raise Refused(413, f"request body too large ({length} bytes; at most {MAX_BODY})")

    async def gather() -> bytes:
        body = bytearray()
        async for chunk in request.stream():
            body += chunk
            if len(body) > MAX_BODY:
                raise Refused(413, f"request body too large (more than {MAX_BODY} bytes)")
        return bytes(body)

    try:
        raw = await asyncio.wait_for(gather(), BODY_TIMEOUT)
    except asyncio.TimeoutError:
        raise Refused(408, f"the request body did not arrive within {BODY_TIMEOUT:g} s") from None
    except ClientDisconnect:  # no one is left to read the answer
        raise Refused(400, "the client left before its request body was complete") from None
    try:
        doc = json.loads(raw or b"{}")
    except RecursionError:
        raise InputError("request body is nested too deeply to be a request") from None
    except ValueError:
        raise InputError("request body must be JSON, e.g. {\"frame\": \"ee\", \"pos\": [0.4, 0, 0.5]}") from None
    if not isinstance(doc, dict):
        raise InputError(f"request body must be a JSON object, got {type(doc).__name__}")
    return doc


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{what} must be a number, got {json.dumps(value)}")
    try:
        return float(value)
    except OverflowError:  # an integer of hundreds of digits
        raise InputError(f"{what} must be a number within floating point range (about 1e308), got an integer of "
                         f"{len(str(abs(value)))} digits") from None


def _numbers(value: Any, n: int, what: str) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise InputError(f"{what} must be a list of {n} numbers, got {json.dumps(value)}")
    return tuple(_number(v, what) for v in value)


def _text(doc: dict, key: str) -> str:
    value = doc.get(key)
    if not isinstance(value, str) or not value:
        raise InputError(f"the request needs \"{key}\": a name (string), got {json.dumps(value)}")
    return value


def _view_event(doc: dict) -> core.ViewEvent:
    """The camera move of a ``POST /view`` body: exactly one of ``orbit``, ``zoom``, ``reset``."""
    given = [k for k in ("orbit", "zoom", "reset") if k in doc]
    if len(given) != 1:
        raise InputError("a view change needs exactly one of \"orbit\": [d_azimuth, d_elevation] (degrees), "
                         f"\"zoom\": factor (below 1: closer) or \"reset\": true; got keys {json.dumps(sorted(doc))}")
    if "orbit" in doc:
        azimuth, elevation = _numbers(doc["orbit"], 2, "orbit")
        return core.Orbit(azimuth, elevation)
    if "zoom" in doc:
        return core.Zoom(_number(doc["zoom"], "zoom"))
    if doc["reset"] is not True:
        raise InputError(f"\"reset\" must be true (back to the initial camera), got {json.dumps(doc['reset'])}")
    return core.ResetView()


def _target(pg: Playground, who: str, doc: dict) -> dict:
    quat = doc.get("quat")
    return pg.apply(who, core.Place(_text(doc, "frame"), _numbers(doc.get("pos"), 3, "pos"),  # type: ignore[arg-type]
                                    None if quat is None else _numbers(quat, 4, "quat")))  # type: ignore[arg-type]


def _drag(pg: Playground, who: str, doc: dict) -> dict:
    frame = _text(doc, "frame")
    if "uv" in doc:
        return pg.apply(who, core.Drag(frame, _numbers(doc["uv"], 2, "uv")))  # type: ignore[arg-type]
    if "depth" in doc:
        return pg.apply(who, core.Push(frame, _number(doc["depth"], "depth")))
    if "turn" in doc:
        return pg.apply(who, core.Turn(frame, _number(doc["turn"], "turn")))
    raise InputError("a drag needs \"uv\": [u, v] (image fractions), \"depth\": metres or \"turn\": radians")


def _frames(pg: Playground, who: str, doc: dict) -> dict:
    frames = doc.get("frames")
    if not isinstance(frames, list) or not all(isinstance(f, str) for f in frames):
        raise InputError(f"\"frames\" must be a list of site or body names, got {json.dumps(frames)}")
    return pg.set_frames(who, frames)


def _step(pg: Playground, who: str, doc: dict) -> dict:
    on = doc.get("on")
    if not isinstance(on, bool):
        raise InputError(f"\"on\" must be true or false, got {json.dumps(on)}")
    return pg.set_step(who, on)


def _constraints(pg: Playground, who: str, doc: dict) -> dict:
    flags = {k: doc.get(k) for k in ("clearance", "balance")}
    if set(doc) - {*flags, "max_joint_speed"} or not doc or any(v is not None and not isinstance(v, bool)
                                                                for v in flags.values()):
        raise InputError("constraints take \"clearance\" and/or \"balance\": true or false, and/or "
                         f"\"max_joint_speed\": rad/s or null, got {json.dumps(doc)}")
    speed = doc.get("max_joint_speed")
    speed = None if speed is None else _number(speed, "max_joint_speed")
    reply = pg.set_constraints(who, flags["clearance"], flags["balance"]) if any(k in doc for k in flags) else {}
    return pg.set_max_joint_speed(who, speed) if "max_joint_speed" in doc else reply


def _solutions(pg: Playground, who: str, doc: dict) -> dict:
    if not doc:
        return pg.find_solutions(who)
    if set(doc) == {"next"} and doc["next"] is True:
        return pg.show_solution(who)
    index = doc.get("index")
    if set(doc) != {"index"} or isinstance(index, bool) or not isinstance(index, int):
        raise InputError(f"solutions take {{}} (find them), {{\"next\": true}} or {{\"index\": i}} (an integer), "
                         f"got {json.dumps(doc)}")
    return pg.show_solution(who, index)


# POST /NAME with a JSON body, as a client: the new state (blocking: a solve may run); MjkinError for a bad request
ACTIONS: dict[str, Callable[[Playground, str, dict], dict]] = {
    "target": _target,
    "drag": _drag,
    "view": lambda pg, who, doc: pg.apply(who, _view_event(doc)),
    "method": lambda pg, who, doc: pg.set_method(who, _text(doc, "method")),
    "goal": lambda pg, who, doc: pg.set_goal(who, _text(doc, "goal")),
    "frames": _frames,
    "joint": lambda pg, who, doc: pg.set_joint(who, _text(doc, "joint"), _number(doc.get("value"), "value")),
    "step": _step,
    "constraints": _constraints,
    "solutions": _solutions,
    "reset": lambda pg, who, doc: pg.reset(who),
    "record": lambda pg, who, doc: pg.record(who),
    "stop": lambda pg, who, doc: pg.stop(who),
}
PAGES = ("/", "/state", "/info", "/frame.jpg", "/stream.mjpg")


# ------------------------------------------------------------------ streams
class FrameFeed:
    """Wakes the streams (coroutines on the server's loop) when the render thread has a new frame."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self.event = asyncio.Event()

    def notify(self) -> None:
        """From any thread: a frame is ready (or the playground stops)."""
        loop = self.loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._pulse)
            except RuntimeError:  # the loop closed meanwhile: no stream is left to wake
                pass

    def _pulse(self) -> None:
        self.event.set()
        self.event = asyncio.Event()


class Routes:
    """The endpoints of one :class:`Playground` (see the module docstring)."""

    def __init__(self, playground: Playground) -> None:
        self.pg = playground
        self.feed = FrameFeed()
        playground.watch(self.feed.notify)
        self.streams = 0  # open /stream.mjpg responses
        self.ending = False  # the server stops: streams end

    def app(self, token: str, hosts: frozenset[str]) -> ASGIApp:
        """The ASGI app: these routes behind the :class:`Door`."""
        routes = [Route("/", self.page), Route("/index.html", self.page), Route("/state", self.state),
                  Route("/info", self.info), Route("/frame.jpg", self.frame), Route("/stream.mjpg", self.stream),
                  *(Route(f"/{name}", self.post, methods=["POST"]) for name in ACTIONS)]
        handlers: dict[Any, Callable[[Request, Exception], Awaitable[Response]]] = {
            404: self.not_found, 405: self.not_allowed}
        return Door(Starlette(routes=routes, exception_handlers=handlers), token, hosts)

    async def page(self, request: Request) -> Response:
        """The page."""
        body = files("mjkin.apps.play").joinpath("static", "index.html").read_bytes()
        return Response(body, headers={**NO_STORE, "Referrer-Policy": "no-referrer"},
                        media_type="text/html; charset=utf-8")

    async def state(self, request: Request) -> Response:
        """``GET /state``."""
        return reply(await run_in_threadpool(self.pg.snapshot))

    async def info(self, request: Request) -> Response:
        """``GET /info``."""
        return reply(self.pg.info())

    async def frame(self, request: Request) -> Response:
        """``GET /frame.jpg``: waits (in a worker thread) for a frame of the state as of the request."""
        try:
            _, jpeg = await run_in_threadpool(self.pg.frame)
        except MjkinError as e:
            return error(503, str(e))
        return Response(jpeg, headers=NO_STORE, media_type="image/jpeg")

    async def stream(self, request: Request) -> Response:
        """``GET /stream.mjpg``."""
        self.feed.loop = asyncio.get_running_loop()
        return StreamingResponse(self.parts(), headers=NO_STORE,
                                 media_type=f"multipart/x-mixed-replace; boundary={BOUNDARY}")

    async def parts(self) -> AsyncIterator[bytes]:
        """The stream's bytes: the first part's headers, then each new image with the next part's headers."""
        self.streams += 1
        try:
            yield PART[2:]
            number = -1
            while not (self.ending or self.pg.closed):
                wake = self.feed.event  # taken before looking: a frame published after the look still wakes us
                got = self.pg.next_frame(number, 0.0)
                if got is None:
                    try:
                        await asyncio.wait_for(wake.wait(), 1.0)
                    except asyncio.TimeoutError:
                        pass
                    continue
                number, jpeg = got
                # each image is followed at once by the next part's headers: browsers show a part only when
                # the next one has begun, so the parts carry no length (a reader splits on PART)
                yield jpeg + PART
        finally:
            self.streams -= 1

    def end_streams(self) -> None:
        """Let every stream end (the server stops)."""
        self.ending = True
        self.feed.notify()

    async def post(self, request: Request) -> Response:
        """``POST /action``: the body read here, the action run in a worker thread."""
        try:
            doc = await read_json(request)
            who = request.headers.get("x-mjkin-client") or (request.client.host if request.client else "?")
            return reply(await run_in_threadpool(ACTIONS[request.url.path[1:]], self.pg, who, doc))
        except Refused as e:
            return error(e.status, str(e), CLOSE)
        except Busy as e:
            return error(409, str(e))
        except MjkinIOError as e:
            return error(500, str(e))
        except MjkinError as e:
            return error(400, str(e))

    async def not_found(self, request: Request, exc: Exception) -> Response:
        """404 in one line."""
        path = request.url.path
        if request.method == "POST":
            return error(404, f"no such action {path!r}; POST {', '.join(f'/{a}' for a in ACTIONS)}")
        return error(404, f"no such page {path!r}; GET {', '.join(PAGES)}")

    async def not_allowed(self, request: Request, exc: Exception) -> Response:
        """405 in one line."""
        path = request.url.path
        return error(405, f"{request.method} {path} is not served: " + (f"POST {path} changes the state"
                     if path[1:] in ACTIONS else f"GET {path} reads it"))


# ------------------------------------------------------------------ the server
class Gate:
    """The connection cap of one server: only connections that have shown the token count against it.

    A connection that has not (it sent nothing yet, or a request without the token, which the
    :class:`Door` refuses and closes) holds no place that a page needs: anyone on the machine can
    open sockets, only the URL's holder can fill the cap.
    """

    def __init__(self, token: str) -> None:
        self.token = token
        self.admitted: set[asyncio.Protocol] = set()  # connections that have shown the token, until they close

    def admit(self, conn: asyncio.Protocol, scope: Scope) -> bool:
        """Count ``conn`` once a request of it (``scope``) shows the token; False: the cap is full."""
        if conn in self.admitted or not has_token(scope, self.token):
            return True  # counted already, or the door refuses it
        if len(self.admitted) >= MAX_CONNECTIONS:
            return False
        self.admitted.add(conn)
        return True


class GatedH11(H11Protocol):
    """uvicorn's h11 protocol under the :class:`Gate` of its server (:func:`gated` makes the class for one).

    A new connection must complete its first request head within :data:`HEAD_TIMEOUT` seconds
    (bytes that do not complete one keep the clock running), later ones within the idle timeout:
    uvicorn times out a connection between requests only, and one that connects and says nothing
    (or half a request) would stay open for ever.
    """

    gate: ClassVar[Gate]

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        """Pass every request through the gate; start the head clock at once."""
        super().connection_made(transport)
        self.app = self.through_gate
        self.timeout_keep_alive_task = self.loop.call_later(HEAD_TIMEOUT, self.timeout_keep_alive_handler)

    def connection_lost(self, exc: Exception | None) -> None:
        """Free the connection's place under the cap."""
        self.gate.admitted.discard(self)
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        """Bytes that do not complete a request keep the clock running."""
        idle, self.timeout_keep_alive_task = self.timeout_keep_alive_task, None
        super().data_received(data)
        if idle is None:
            return
        if (self.cycle is None or self.cycle.response_complete) and self.timeout_keep_alive_task is None:
            self.timeout_keep_alive_task = idle
        else:
            idle.cancel()

    async def through_gate(self, scope: Scope, receive: Receive, send: Send) -> None:
        """The app, once the gate lets this connection in; a 503 (and the connection closed) when the cap is full."""
        if self.gate.admit(self, scope):
            await self.config.loaded_app(scope, receive, send)
        else:
            await error(503, f"the playground serves at most {MAX_CONNECTIONS} connections at once (a page keeps "
                             "2-3); close other pages or clients, then try again", CLOSE)(scope, receive, send)


def gated(gate: Gate) -> type[GatedH11]:
    """The protocol class of one server: :class:`GatedH11` under ``gate``."""
    return type("GatedH11", (GatedH11,), {"gate": gate})


class _Uvicorn(uvicorn.Server):
    """uvicorn's server; its shutdown ends the streams first (they would run until the playground closes).

    SIGTERM (``kill``, ``docker stop``, ``systemctl stop``) is taken as Ctrl-C: uvicorn shuts down gracefully on
    either, then raises the signal again once its handlers are restored, and a SIGTERM raised again would kill the
    process before :func:`serve` saves the take; a SIGINT raised again is the ``KeyboardInterrupt`` it expects.
    """

    def __init__(self, config: uvicorn.Config, routes: Routes) -> None:
        super().__init__(config)
        self.routes = routes

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        """End the streams, then shut down as uvicorn does."""
        self.routes.end_streams()
        await super().shutdown(sockets)

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        """A signal to stop: SIGTERM is handled as SIGINT (a second one forces the exit, as a second Ctrl-C)."""
        super().handle_exit(signal.SIGINT if sig == signal.SIGTERM else sig, frame)


class PlayServer:
    """One :class:`Playground` served on a bound socket: :meth:`serve_forever` (this thread), :meth:`shutdown`."""

    def __init__(self, playground: Playground, sock: socket.socket, host: str,
                 idle_timeout: int = IDLE_TIMEOUT) -> None:
        self.playground, self.socket = playground, sock
        self.server_address: tuple[str, int] = sock.getsockname()[:2]
        self.token = secrets.token_urlsafe(32)
        self.routes = Routes(playground)
        bound, port = self.server_address
        app = self.routes.app(self.token, host_names(host, port, bound))
        config = uvicorn.Config(app, http=gated(Gate(self.token)), ws="none", lifespan="off", log_config=None,
                                log_level="error", access_log=False, proxy_headers=False, server_header=False,
                                backlog=BACKLOG, timeout_keep_alive=idle_timeout,
                                timeout_graceful_shutdown=SHUTDOWN_TIMEOUT)
        self.server = _Uvicorn(config, self.routes)

    @property
    def url(self) -> str:
        """The page's address, with the token."""
        host, port = self.server_address
        return f"http://{f'[{host}]' if ':' in host else host}:{port}/?token={self.token}"

    def serve_forever(self) -> None:
        """Serve until :meth:`shutdown` or, in the main thread, Ctrl-C or SIGTERM (taken as Ctrl-C)."""
        self.server.run(sockets=[self.socket])

    def shutdown(self) -> None:
        """Ask :meth:`serve_forever` to return (from another thread)."""
        self.server.should_exit = True

    def close(self) -> None:
        """Close the listening socket."""
        self.socket.close()


def is_loopback(host: str) -> bool:
    """``host`` is a loopback name or address."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def has_display() -> bool:
    """A browser can open a window here."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def start_server(playground: Playground, host: str = "127.0.0.1", port: int = 0,
                 idle_timeout: int = IDLE_TIMEOUT) -> tuple[PlayServer, threading.Thread]:
    """Serve ``playground`` from a background thread (tests, benchmarks); stop with :func:`stop_server`."""
    server = bind(playground, host, port, idle_timeout)
    thread = threading.Thread(target=server.serve_forever, name="mjkin-play-http")
    thread.start()
    return server, thread


def stop_server(server: PlayServer, thread: threading.Thread) -> None:
    """Stop a server from :func:`start_server`, its playground and its threads."""
    server.playground.close()
    server.shutdown()
    thread.join()
    server.close()


def bind(playground: Playground, host: str, port: int, idle_timeout: int = IDLE_TIMEOUT) -> PlayServer:
    """A server for ``playground`` listening on ``host:port`` (0: any free port); a port in use is a one-line error."""
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be in 0..65535, got {port}")
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # proto TCP, not 0: asyncio turns Nagle off only on sockets that say so, and with Nagle on a reply's body waits
    # for the client's delayed ACK of its headers (40 ms a request)
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    try:
        if os.name == "posix":
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a restart may reuse a port just left
        sock.bind((host, port))
        sock.listen(BACKLOG)
    except OSError as e:
        sock.close()
        raise MjkinIOError(f"cannot serve on {host}:{port} ({e.strerror or e}); "
                           "choose another --port or --host") from None
    return PlayServer(playground, sock, host, idle_timeout)


def recover_journals(folder: Path) -> None:
    """Turn the journals of recordings cut short in ``folder`` into scripts, one line on stderr for each."""
    for path in journal.leftovers(folder):
        say(rescue(path, "a recording cut short"))


def rescue(path: Path, what: str) -> str:
    """Write the script of ``what`` from its journal ``path``; the line that says how it went."""
    try:
        script = journal.recover(path)
    except MjkinError as e:
        return f"{what} stays in its journal {str(path)!r} (the next mjkin play here tries again): {e}"
    if script is None:
        return f"{what} held no sample; its journal {str(path)!r} is removed"
    return (f"{what} is saved as {str(script)!r} from its journal (no video: mjkin replay {script} -o take.mp4 "
            "makes one)")


def say(line: str) -> None:
    """One line on stderr, as ``mjkin play: ...``."""
    print(f"mjkin play: {line}", file=sys.stderr, flush=True)


def serve(model: str | Path | Tree = "arm7", host: str = "127.0.0.1", port: int = 8765, browser: bool = True,
          out_dir: str | Path = ".") -> int:
    """Run ``mjkin play`` until Ctrl-C or SIGTERM: print the URL (with its token), open a browser on a display."""
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be in 0..65535, got {port}")
    tree = model if isinstance(model, Tree) else load(model)
    recover_journals(recordings_folder(out_dir, tree.name or "model"))  # before the long start
    if not is_loopback(host):
        say(f"warning: serving on {host}, not loopback: anyone who can reach it and has the URL (its token) "
            "can control the playground")
    say(f"loading {tree.name or model}...")  # a first run's compilation says so itself (mjkin.runtime.progress)

    playground = Playground(tree, out_dir=out_dir, source="" if isinstance(model, Tree) else source_of(str(model)))
    try:
        server = bind(playground, host, port)
    except BaseException:
        playground.close()
        raise
    playground.start()
    print(f"mjkin play: {server.url}  (Ctrl-C stops)", flush=True)
    if browser and has_display():
        threading.Thread(target=webbrowser.open, args=(server.url,), daemon=True).start()
    try:
        with contextlib.suppress(KeyboardInterrupt):  # uvicorn takes Ctrl-C (and SIGTERM), shuts down and returns
            server.serve_forever()
        say("stopped")
    finally:
        if playground.exporting:
            say("finishing the recording being written...")
        left = "the recording that was on" if playground.recording else "the recording not written"
        playground.close()
        server.close()
        if playground.journal is not None:
            say(rescue(playground.journal, left))
    return 0
