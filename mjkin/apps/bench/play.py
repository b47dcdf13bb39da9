"""``mjkin bench play``: the playground's frame rate and drag-to-new-frame latency, over real HTTP.

A server runs in this process on a free loopback port. Frame rate: a client reads
the MJPEG stream while another drags the target along a circle at a mouse's rate
(60 moves a second, one request in flight, as the page does); frames received per
second. Latency: ``POST /drag`` (the solve runs) then ``GET /frame.jpg`` (which
waits for a frame of the new state), timed from sending the drag to holding the
JPEG. The baseline is the bare renderer with the same settings plus the JPEG
encoding: the most any server on this machine could stream.
"""

from __future__ import annotations

import http.client
import json
import socket
import tempfile
import threading
import time

import numpy as np

from ...kinematics.tree import Tree, load
from ...motion.trajectory import Trajectory
from ..play.server import PART, start_server, stop_server
from ..play.session import Playground, encode_jpeg, live_painter

Row = dict[str, object]
MOUSE_HZ = 60.0  # drags per second in the frame-rate run, as a mouse moves


def _post(conn: http.client.HTTPConnection, token: str, path: str, doc: dict) -> dict:
    conn.request("POST", path, json.dumps(doc), {"Content-Type": "application/json", "X-Mjkin-Token": token})
    return dict(json.loads(conn.getresponse().read()))


def _stream_frames(host: str, port: int, token: str, stop: threading.Event, stamps: list[float]) -> None:
    """Read the MJPEG stream as a browser would; stamp the time each image is complete."""
    with socket.create_connection((host, port), timeout=10) as sock:
        sock.sendall(f"GET /stream.mjpg?token={token} HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode())
        sock.settimeout(0.2)  # to see ``stop`` when no frame comes
        buffer, body = b"", False
        while not stop.is_set():
            try:
                chunk = sock.recv(1 << 16)
            except TimeoutError:
                continue
            if not chunk:
                break
            buffer += chunk
            if not body:  # skip the response headers: their blank line would look like a part's start
                if b"\r\n\r\n" not in buffer:
                    continue
                buffer, body = buffer.split(b"\r\n\r\n", 1)[1], True
            parts = buffer.split(PART)
            stamps.extend([time.perf_counter()] * (len(parts) - 1))  # one image ends at each PART
            buffer = parts[-1]


def _circle(view_uv: np.ndarray, k: int, n: int, radius: float = 0.06) -> list[float]:
    phi = 2 * np.pi * k / n
    return [float(view_uv[0] + radius * np.cos(phi)), float(view_uv[1] + radius * np.sin(phi))]


def measure(models: tuple[str, ...] = ("arm7", "primate"), width: int = 640, height: int = 480,
            seconds: float = 3.0, drags: int = 40) -> dict[str, list[Row]]:
    """One row per model: frames/s while dragging, drag→frame latency, the bare renderer's frames/s, save speed."""
    rows = [measure_model(m, width, height, seconds, drags) for m in models]
    return {f"mjkin play at {width}x{height}, offscreen GL: {seconds:g} s of dragging for the frame rate, {drags} "
            f"timed drags (POST /drag, then GET /frame.jpg) for the latency, {seconds:g} s of dragging recorded, then "
            "POST /stop to that take's video saved; goals: >= 15 frames/s, <= 100 ms, <= 0.5 s of saving per s of "
            "take": rows}


def _drag(conn: http.client.HTTPConnection, token: str, frame: str, start_uv: np.ndarray, seconds: float) -> int:
    """Drag ``frame``'s target along a circle for ``seconds`` as a mouse does; the number of drags sent."""
    begin = time.perf_counter()
    k, end = 0, begin + seconds
    while time.perf_counter() < end:  # a mouse reports about 60 moves a second; the page sends one at a time
        _post(conn, token, "/drag", {"frame": frame, "uv": _circle(start_uv, k, 60)})
        k += 1
        time.sleep(max(0.0, begin + k / MOUSE_HZ - time.perf_counter()))
    return k


def _saved(conn: http.client.HTTPConnection, token: str, timeout: float = 600.0) -> dict:
    """Poll ``/state`` as the page does until the take's save is done; its final report."""
    deadline = time.perf_counter() + timeout
    while time.perf_counter() < deadline:
        conn.request("GET", "/state", headers={"X-Mjkin-Token": token})
        save = dict(json.loads(conn.getresponse().read())["save"])
        if save["done"] or save["error"]:
            return save
        time.sleep(0.02)
    raise TimeoutError(f"the take was not saved within {timeout:g} s")


def measure_model(model: str, width: int, height: int, seconds: float, drags: int) -> Row:
    """Frames/s while dragging ``model``'s first target, drag→frame latency (median, p95), bare frames/s, and the
    seconds of saving per second of a take (recorded while dragging, saved in a temporary folder).
    """  # noqa: D205
    tree = load(model)
    with tempfile.TemporaryDirectory(prefix="mjkin-bench-play-") as takes:
        return _measure(model, tree, Playground(tree, width, height, out_dir=takes).start(), seconds, drags)


def _measure(model: str, tree: Tree, pg: Playground, seconds: float, drags: int) -> Row:
    server, thread = start_server(pg)
    host, port, token = "127.0.0.1", server.server_address[1], server.token
    try:
        conn = http.client.HTTPConnection(host, port, timeout=30)
        frame = next(iter(pg.state.targets))
        start_uv = pg.view.project(np.asarray(pg.state.targets[frame])[:3])
        # warm: the first drag's solve may compile (or wait for another process's compile), which no figure times
        _post(conn, token, "/drag", {"frame": frame, "uv": _circle(start_uv, 0, 60)})
        conn.request("GET", "/frame.jpg", headers={"X-Mjkin-Token": token})
        conn.getresponse().read()
        # frame rate: a viewer on the stream, a drag on every answer
        stamps: list[float] = []
        stop = threading.Event()
        viewer = threading.Thread(target=_stream_frames, args=(host, port, token, stop, stamps))
        viewer.start()
        end = time.perf_counter() + seconds
        k = _drag(conn, token, frame, start_uv, seconds)
        time.sleep(0.2)
        stop.set()
        viewer.join()
        window = [t for t in stamps if t <= end]
        fps = (len(window) - 1) / (window[-1] - window[0]) if len(window) > 1 else 0.0
        # latency: drag, then the first frame of the new state
        lat = []
        for i in range(drags):
            t0 = time.perf_counter()
            _post(conn, token, "/drag", {"frame": frame, "uv": _circle(start_uv, i, drags)})
            conn.request("GET", "/frame.jpg", headers={"X-Mjkin-Token": token})
            conn.getresponse().read()
            lat.append(time.perf_counter() - t0)
        # saving: a take of ``seconds`` of dragging, from POST /stop to its video written
        _post(conn, token, "/record", {})
        _drag(conn, token, frame, start_uv, seconds)
        t0 = time.perf_counter()
        _post(conn, token, "/stop", {})
        save = _saved(conn, token)
        save_s = time.perf_counter() - t0
        if save["error"]:
            raise RuntimeError(f"the take was not saved: {save['error']}")
        take_s = float(Trajectory.load(save["path"], tree).times[-1])
        conn.close()
        # baseline: the renderer alone with JPEG encoding, same size and camera
        qs = tree.random_q(np.random.default_rng(0), 30)
        camera = pg.camera.mjv(tree.model)
        with live_painter(tree, pg.width, pg.height) as painter:
            painter.draw(qs[0], camera)
            t0 = time.perf_counter()
            for q in qs:
                encode_jpeg(painter.draw(q, camera))
            bare = len(qs) / (time.perf_counter() - t0)
    finally:
        stop_server(server, thread)
    ms = 1e3 * np.array(lat)
    return {"model": model, "targets": len(pg.state.targets), "stream frames/s": fps,
            "bare renderer + JPEG frames/s": bare, "ratio": fps / bare,
            "latency median ms": float(np.median(ms)), "latency p95 ms": float(np.percentile(ms, 95)),
            "drags/s sent": k / seconds, "take s": take_s, "save s per take s": save_s / take_s}
