"""``mjkin play``'s HTTP server: the page, a small JSON API, single JPEG frames and an MJPEG stream.

Standard library only (:class:`http.server.ThreadingHTTPServer`). Routes (JSON in and out):

- ``GET /`` the page; ``GET /info`` methods, goal kinds, frames, joint sliders, image size.
- ``GET /state`` → ``{"model", "q", "targets": {frame: [x, y, z, qw, qx, qy, qz]}, "error": [pos, rot],
  "iterations", "method", ...}`` (also ``goal``, ``status``, ``success``, ``singular_values``,
  ``manipulability``, ``step``, ``recording``, ``unsaved`` (a stopped recording not yet written), ``screen``:
  each target's image point ``[u, v]``, ``camera``: ``{"lookat", "distance", "azimuth", "elevation"}``).
- ``POST /target`` ``{"frame", "pos": [x, y, z], "quat"?: [w, x, y, z]}`` → the solve runs, the new state.
- ``POST /drag`` ``{"frame", "uv": [u, v]}`` (image fractions, top-left origin), ``{"frame", "depth": m}``
  (along the line of sight) or ``{"frame", "turn": rad}`` (about it, for pose goals).
- ``POST /view`` ``{"orbit": [d_azimuth, d_elevation]}`` (degrees, about the look-at point), ``{"zoom": factor}``
  (the distance times it; below 1: closer) or ``{"reset": true}`` (the initial camera); later drags use the new view.
- ``POST /method`` ``{"method"}``, ``/goal`` ``{"goal"}``, ``/frames`` ``{"frames": [...]}``,
  ``/joint`` ``{"joint", "value"}``, ``/step`` ``{"on": bool}``, ``/reset`` ``{}``.
- ``POST /record`` ``{}`` starts recording; ``POST /stop`` ``{}`` writes the script and the mp4 →
  ``{"path", "video", "frames"}`` (into the folder checked writable at the start).
- ``GET /frame.jpg`` the current frame (waits until it shows the current state);
  ``GET /stream.mjpg`` every new frame (``multipart/x-mixed-replace``, parts split by :data:`PART`).

A bad request is a 400 with ``{"error": "one line"}``; a change while another client
holds control is a 409 (see :mod:`mjkin.play.session`); a recording that cannot be written is a 500
(it is kept: ``POST /stop`` again writes it). Every reply is strict JSON: a number that is not finite
(an image point of a target level with the camera, say) is sent as ``null``.
"""

from __future__ import annotations

import ipaddress
import json
import os
import select
import socket
import sys
import threading
import webbrowser
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib.resources import files
from pathlib import Path
from typing import Any

from ..errors import InputError, MjkinError, MjkinIOError
from ..files import strict_json
from ..tree import Tree, load
from . import core
from .session import Busy, Playground, recordings_folder

MAX_BODY = 1 << 16
BOUNDARY = "mjkin-play-frame"
PART = f"\r\n--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n\r\n".encode()  # ends one image, starts the next
STREAM_THREAD = "mjkin-play-stream"  # the name of a thread serving /stream.mjpg
STALL_TIMEOUT = 5.0  # seconds a stream write may wait for a viewer that no longer reads


class PlayServer(ThreadingHTTPServer):
    """A threading HTTP server that serves one :class:`Playground`."""

    daemon_threads = True

    def __init__(self, address: tuple[str, int], playground: Playground) -> None:
        self.playground = playground
        super().__init__(address, Handler)

    @property
    def url(self) -> str:
        """The page's address."""
        host, port = self.server_address[:2]
        host = str(host)
        return f"http://{f'[{host}]' if ':' in host else host}:{port}/"


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{what} must be a number, got {json.dumps(value)}")
    return float(value)


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


class Handler(BaseHTTPRequestHandler):
    """Routes of the playground (see the module docstring)."""

    server: PlayServer
    protocol_version = "HTTP/1.1"
    timeout = 60
    disable_nagle_algorithm = True  # headers and body go out in two writes: Nagle would hold the body ~40 ms

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002  (quiet: the terminal shows the URL)
        """Do not log every request."""

    # ------------------------------------------------------------- replies
    def _send(self, status: int, body: bytes, kind: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, doc: object, status: int = 200) -> None:
        self._send(status, strict_json(doc).encode(), "application/json")

    def _error(self, status: int, message: str) -> None:
        self._json({"error": " ".join(message.split())}, status)

    @property
    def client(self) -> str:
        """Who is asking: the page's id, else the address."""
        return self.headers.get("X-Mjkin-Client") or self.client_address[0]

    def _body(self) -> dict:
        try:
            length = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            raise InputError("Content-Length must be a number") from None
        if length > MAX_BODY:
            raise InputError(f"request body too large ({length} bytes; at most {MAX_BODY})")
        raw = self.rfile.read(length) if length else b"{}"
        try:
            doc = json.loads(raw or b"{}")
        except ValueError:
            raise InputError("request body must be JSON, e.g. {\"frame\": \"ee\", \"pos\": [0.4, 0, 0.5]}") from None
        if not isinstance(doc, dict):
            raise InputError(f"request body must be a JSON object, got {type(doc).__name__}")
        return doc

    # -------------------------------------------------------------- routes
    def do_GET(self) -> None:  # noqa: N802
        """Serve the page, the state, a frame or the stream."""
        pg = self.server.playground
        path = self.path.split("?", 1)[0]
        try:
            if path in ("/", "/index.html"):
                page = files("mjkin.play").joinpath("static", "index.html").read_bytes()
                self._send(200, page, "text/html; charset=utf-8")
            elif path == "/state":
                self._json(pg.snapshot())
            elif path == "/info":
                self._json(pg.info())
            elif path == "/frame.jpg":
                self._send(200, pg.frame()[1], "image/jpeg")
            elif path == "/stream.mjpg":
                self._stream()
            else:
                self._error(404, f"no such page {path!r}; try /, /state, /info, /frame.jpg or /stream.mjpg")
        except MjkinError as e:
            self._error(503, str(e))
        except (BrokenPipeError, ConnectionResetError, ConnectionAbortedError, TimeoutError):
            self.close_connection = True

    def do_POST(self) -> None:  # noqa: N802
        """Change the state (see the module docstring for the routes)."""
        pg, path = self.server.playground, self.path.split("?", 1)[0]
        try:
            doc = self._body()
            who = self.client
            if path == "/target":
                quat = doc.get("quat")
                event = core.Place(_text(doc, "frame"), _numbers(doc.get("pos"), 3, "pos"),  # type: ignore[arg-type]
                                   None if quat is None else _numbers(quat, 4, "quat"))  # type: ignore[arg-type]
                self._json(pg.apply(who, event))
            elif path == "/drag":
                frame = _text(doc, "frame")
                if "uv" in doc:
                    self._json(pg.apply(who, core.Drag(frame, _numbers(doc["uv"], 2, "uv"))))  # type: ignore[arg-type]
                elif "depth" in doc:
                    self._json(pg.apply(who, core.Push(frame, _number(doc["depth"], "depth"))))
                elif "turn" in doc:
                    self._json(pg.apply(who, core.Turn(frame, _number(doc["turn"], "turn"))))
                else:
                    raise InputError("a drag needs \"uv\": [u, v] (image fractions), \"depth\": metres "
                                     "or \"turn\": radians")
            elif path == "/view":
                self._json(pg.apply(who, _view_event(doc)))
            elif path == "/method":
                self._json(pg.set_method(who, _text(doc, "method")))
            elif path == "/goal":
                self._json(pg.set_goal(who, _text(doc, "goal")))
            elif path == "/frames":
                frames = doc.get("frames")
                if not isinstance(frames, list) or not all(isinstance(f, str) for f in frames):
                    raise InputError(f"\"frames\" must be a list of site or body names, got {json.dumps(frames)}")
                self._json(pg.set_frames(who, frames))
            elif path == "/joint":
                self._json(pg.set_joint(who, _text(doc, "joint"), _number(doc.get("value"), "value")))
            elif path == "/step":
                on = doc.get("on")
                if not isinstance(on, bool):
                    raise InputError(f"\"on\" must be true or false, got {json.dumps(on)}")
                self._json(pg.set_step(who, on))
            elif path == "/reset":
                self._json(pg.reset(who))
            elif path == "/record":
                self._json(pg.record(who))
            elif path == "/stop":
                self._json(pg.stop(who))
            else:
                self._error(404, f"no such action {path!r}; POST /target, /drag, /view, /method, /goal, /frames, "
                                 "/joint, /step, /reset, /record or /stop")
        except Busy as e:
            self._error(409, str(e))
        except MjkinIOError as e:
            self._error(500, str(e))
        except MjkinError as e:
            self._error(400, str(e))
        except (BrokenPipeError, ConnectionResetError, ConnectionAbortedError):
            self.close_connection = True

    def _stream(self) -> None:
        """Every new frame as a part of ``multipart/x-mixed-replace``, until the client or the server goes."""
        pg = self.server.playground
        threading.current_thread().name = STREAM_THREAD  # so a lingering stream can be told from other requests
        self.connection.settimeout(STALL_TIMEOUT)  # a viewer that stops reading without closing frees the thread
        self.close_connection = True
        self.send_response(200)
        self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY}")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.wfile.write(PART[2:])
        number = -1
        while not pg.closed and not self._client_gone():
            got = pg.next_frame(number)
            if got is None:
                continue
            number, jpeg = got
            # each image is followed at once by the next part's headers: browsers show a part only when
            # the next one has begun, so the parts carry no length (a reader splits on PART)
            self.wfile.write(jpeg + PART)
            self.wfile.flush()


    def _client_gone(self) -> bool:
        """The viewer closed its end (a stream client only ever sends its request)."""
        try:
            readable, _, _ = select.select([self.connection], [], [], 0)
            return bool(readable) and self.connection.recv(1, socket.MSG_PEEK) == b""
        except OSError:
            return True


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


def start_server(playground: Playground, host: str = "127.0.0.1", port: int = 0) -> tuple[PlayServer, threading.Thread]:
    """Serve ``playground`` from a background thread (tests, benchmarks); stop with :func:`stop_server`."""
    server = bind(playground, host, port)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1}, name="mjkin-play-http")
    thread.start()
    return server, thread


def stop_server(server: PlayServer, thread: threading.Thread) -> None:
    """Stop a server from :func:`start_server`, its playground and its threads."""
    server.playground.close()
    server.shutdown()
    thread.join()
    server.server_close()


def bind(playground: Playground, host: str, port: int) -> PlayServer:
    """A server for ``playground`` bound to ``host:port``; a port in use is a one-line error."""
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be in 0..65535, got {port}")
    try:
        return PlayServer((host, port), playground)
    except OSError as e:
        raise MjkinIOError(f"cannot serve on {host}:{port} ({e.strerror or e}); choose another --port or --host") \
            from None


def serve(model: str | Path | Tree = "arm7", host: str = "127.0.0.1", port: int = 8765, browser: bool = True,
          out_dir: str | Path = ".") -> int:
    """Run ``mjkin play`` until Ctrl-C: print the URL, open a browser when there is a display."""
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be in 0..65535, got {port}")
    tree = model if isinstance(model, Tree) else load(model)
    recordings_folder(out_dir, tree.name or "model")  # before the long start
    if not is_loopback(host):
        print(f"mjkin play: warning: serving on {host}, not loopback: anyone who can reach it can control "
              "the playground (there is no login)", file=sys.stderr)
    print(f"mjkin play: loading {tree.name or model} (the first run compiles the IK kernels, about a minute)...",
          file=sys.stderr, flush=True)
    playground = Playground(tree, out_dir=out_dir)
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
        server.serve_forever(poll_interval=0.2)
    except KeyboardInterrupt:
        print("mjkin play: stopped", file=sys.stderr)
    finally:
        if playground.recording:
            print("mjkin play: a recording was on; nothing was written (POST /stop writes it)", file=sys.stderr)
        if playground.unsaved:
            print("mjkin play: a stopped recording could not be written and is lost (see the page's error)",
                  file=sys.stderr)
        if playground.exporting:
            print("mjkin play: finishing the recording being written...", file=sys.stderr)
        playground.close()
        server.server_close()
    return 0
