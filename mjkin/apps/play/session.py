"""The live playground: one state and camera under a lock, a render thread making JPEG frames, recording, control.

Control: the first client that changes something holds control for
:attr:`Playground.lease` seconds after its last change; meanwhile changes from
other clients are refused (:class:`Busy`, HTTP 409) and they watch. A client is
named by the page (a random id it sends with every request), else by its address.

Threads: every GL call of the live view happens in the render thread (an EGL context belongs to the
thread that made it current). It renders when the state or the camera changes, and at the frame
rate while step mode runs or a recording is on; it sleeps otherwise. A stopped take is written by a
save thread of its own (its own context), while the page goes on; :meth:`Playground.close` waits for it.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import mujoco
import numpy as np

from ... import motion, render, spatial
from ...errors import InputError, MjkinError, MjkinIOError
from ...kinematics.tree import Tree
from ...motion.journal import columns
from ...runtime.files import check_writable
from . import core, journal
from .journal import Journal, Sample

AXIS_LENGTH = 0.08  # metres: the target's frame axes drawn on the page for pose goals
TRAIL, TRAIL_STEP = 40, 0.005  # trail points kept, and the least effector move (m) that adds one
# opaque, and a short trail: in software GL each transparent capsule costs about as much as a frame's worth of
# pixels, 120 of them cost five frames (mjkin bench play)
MARKERS = render.Overlay(point_size=0.03, point_rgba=(0.95, 0.2, 0.2, 1.0), trail_rgba=(0.1, 0.5, 0.95, 1.0))
VIDEO_FPS = 30.0  # frames per second of a take's video


class Busy(MjkinError):
    """Another client controls the playground for now."""


@dataclass(frozen=True)
class Recording:
    """A take being recorded: its samples (also in its journal on disk), from ``start`` (monotonic seconds)."""

    samples: list[Sample]
    journal: Journal
    start: float


@dataclass(frozen=True)
class Take:
    """A stopped recording until it is written, with the camera and state when it stopped."""

    recording: Recording
    camera: core.Camera
    state: core.State


@dataclass
class Save:
    """A stopped take written in the background: its script ``path`` and ``video``, ``frames`` samples.

    ``progress`` (0..1) follows the video's frames; then ``done`` (both files written, the journal
    removed) or ``error`` (one line; the take is kept, :meth:`Playground.stop` again writes it).
    """

    path: str
    video: str
    frames: int
    progress: float = 0.0
    done: bool = False
    error: str | None = None

    @property
    def finished(self) -> bool:
        """Written, or failed."""
        return self.done or self.error is not None

    def report(self) -> dict:
        """As JSON: ``{"path", "video", "frames", "progress", "done", "error"}``."""
        return asdict(self)


def recordings_folder(folder: str | Path, model: str) -> Path:
    """``folder`` once a recording can be written there (a probe file is made and removed), else one-line errors.

    Raises:
        MjkinIOError: ``folder`` is missing, not a folder, or not writable.
    """
    path = Path(folder)
    if not path.is_dir():
        raise MjkinIOError(f"recordings folder {str(folder)!r} does not exist or is not a folder; "
                           "give an existing one (--out)")
    try:
        check_writable(path / f"mjkin-play-{model}.mp4")
    except MjkinIOError as e:
        raise MjkinIOError(f"{e}; recordings go there: give a folder you can write (--out)") from None
    return path


def encode_jpeg(image: np.ndarray, quality: int = 80) -> bytes:
    """JPEG bytes of an RGB image ``(H, W, 3)`` (imageio's Pillow plugin)."""
    import imageio.v3 as iio

    return bytes(iio.imwrite("<bytes>", image, extension=".jpg", quality=quality))


def live_painter(tree: Tree, width: int, height: int) -> render.Painter:
    """A painter for the live view: no multisampling, shadows or reflections.

    In software GL (llvmpipe) 4x multisampling makes a 640x480 frame about three
    times slower, shadows and reflections each cost as much again; exported videos
    keep all three (the model's own settings are restored once the context exists).
    """
    quality = tree.model.vis.quality
    samples, quality.offsamples = quality.offsamples, 0
    try:
        painter = render.Painter(tree, width, height)
    finally:
        quality.offsamples = samples
    flags = painter.renderer.scene.flags
    flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
    flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
    return painter


def view_camera(tree: Tree, home: np.ndarray, samples: int = 64) -> mujoco.MjvCamera:
    """A camera on the space the figure reaches from where it stands (random poses, the free root kept at home).

    :func:`mjkin.render.default_camera` frames every geom of every sampled pose.
    """
    qs = np.concatenate([home[None], tree.random_q(np.random.default_rng(0), samples)])
    free = tree.layout.free_q.ravel().astype(int)
    qs[:, free] = home[free]
    return render.default_camera(tree, qs)


class Playground:
    """The state of one ``mjkin play`` session and its render thread (call :meth:`start`, then :meth:`close`)."""

    def __init__(self, tree: Tree, width: int = 640, height: int = 480, fps: float = 30.0, lease: float = 5.0,
                 out_dir: str | Path = ".", frames: Sequence[str] | None = None, source: str = "") -> None:
        if not fps > 0 or not lease >= 0:
            raise InputError(f"fps must be > 0 and lease >= 0, got {fps!r}, {lease!r}")
        self.tree, self.width, self.height, self.fps, self.lease = tree, width, height, fps, lease
        self.out_dir = Path(out_dir)  # checked by serve(); not here: benchmarks and stills never record
        self.source = source  # where the model came from, as scripts record it (a file's path, a bundled name)
        home = core.initial_state(tree, frames)
        self.home = core.Camera.of(view_camera(tree, home.q))  # the initial camera, where "reset view" goes
        self.camera = self.home  # the camera of the moment (orbit, zoom); guarded by the lock like the state
        self.state = core.solve_state(tree, home)  # also compiles the solver before the first client comes
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._closed = threading.Event()
        self._frame_ready = threading.Condition()
        self._watchers: list[Callable[[], None]] = []
        self._version = 0
        self._frame: tuple[int, int, bytes] = (-1, -1, b"")  # (state version, frame number, jpeg)
        self._controller: str | None = None
        self._lease_until = 0.0
        self._recording: Recording | None = None
        self._unsaved: Take | None = None  # stopped, not yet written (being written, or it failed: POST /stop retries)
        self._save: Save | None = None  # the last take's writing: in progress, done or failed
        self._saver: threading.Thread | None = None  # the thread writing it
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._render_loop, name="mjkin-play-render")
        self._solutions: core.Solutions | None = None  # every IK solution of the target, while it stays the target

    # ----------------------------------------------------------- life cycle
    def start(self) -> Playground:
        """Start the render thread; returns self."""
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the render thread, wake every waiting stream, let a recording being written finish (idempotent).

        The journal of a take not written (:attr:`journal`) is flushed and closed, and stays on disk.
        """
        self._closed.set()
        self._wake.set()
        self._notify()
        if self._thread.is_alive():
            self._thread.join()
        with self._lock:  # stop() starts a saver under the lock only while not closed
            saver = self._saver
        if saver is not None:  # a take being written is finished: its video, its script
            saver.join()
        log = self._take_journal
        if log is not None:
            log.close()

    @property
    def _take_journal(self) -> Journal | None:
        """The journal of the take being recorded, or stopped and not yet written."""
        with self._lock:
            take = self._recording or (self._unsaved and self._unsaved.recording)
        return take.journal if take else None

    @property
    def journal(self) -> Path | None:
        """The journal of a take not written yet (being recorded, or stopped and not saved), if any."""
        log = self._take_journal
        return None if log is None else log.path

    def watch(self, callback: Callable[[], None]) -> None:
        """Have ``callback()`` called after every new frame, a render failure and :meth:`close` (from any thread)."""
        self._watchers.append(callback)

    def _notify(self) -> None:
        with self._frame_ready:
            self._frame_ready.notify_all()
        for callback in self._watchers:
            callback()

    @property
    def exporting(self) -> bool:
        """A recording is being written."""
        return self._saver is not None and self._saver.is_alive()

    @property
    def closed(self) -> bool:
        """The playground is shutting down."""
        return self._closed.is_set()

    # -------------------------------------------------------------- control
    def _claim(self, client: str) -> None:
        now = time.monotonic()
        if self._controller not in (None, client) and now < self._lease_until:
            raise Busy(f"another client controls the playground for {self._lease_until - now:.1f} s more; "
                       "watch, or try again then")
        self._controller, self._lease_until = client, now + self.lease

    @property
    def view(self) -> core.View:
        """The view of the camera of the moment: rays and drags, the targets' image points."""
        return core.View.of(self.camera, self.tree.model, self.width, self.height)

    def _change(self, client: str, update: Callable[[core.State], core.State] | None = None,
                look: core.ViewEvent | None = None) -> dict:
        """Apply ``update`` to the state, ``look`` to the camera, as ``client`` (under the lock); the JSON state."""
        with self._lock:
            self._claim(client)
            if update is not None:
                self.state = update(self.state)
            if look is not None:
                self.camera = core.look(self.home, self.camera, look)
            self._version += 1
        self._wake.set()
        return self.snapshot()

    def apply(self, client: str, event: core.Event | core.ViewEvent) -> dict:
        """A drag, push or placement: targets move, IK follows (in step mode, frame by frame); or the camera moves.

        The drag is read in the view of the camera of the moment.
        """
        if isinstance(event, core.ViewEvent):
            return self._change(client, look=event)
        return self._change(client, lambda s: core.apply(self.tree, self.view, s, event))

    def set_method(self, client: str, method: str) -> dict:
        """Switch the IK method (and re-solve, unless in step mode)."""
        return self._change(client, lambda s: self._settle(core.with_method(s, method)))

    def set_goal(self, client: str, goal: str) -> dict:
        """Switch the goal kind (one of :func:`~mjkin.apps.play.core.goal_kinds`: position, pose, aim, ...)."""
        return self._change(client, lambda s: self._settle(core.with_goal(s, goal)))

    def set_frames(self, client: str, frames: Sequence[str]) -> dict:
        """Choose the effector frames (sites or bodies)."""
        return self._change(client, lambda s: self._settle(core.with_frames(self.tree, s, frames)))

    def set_joint(self, client: str, joint: str, value: float) -> dict:
        """Forward kinematics: move one joint; the targets follow the effectors."""
        return self._change(client, lambda s: core.with_joint(self.tree, s, joint, value))

    def set_step(self, client: str, on: bool) -> dict:
        """Step mode on (one solver iteration per frame) or off (solve at once)."""
        return self._change(client, lambda s: self._settle(replace(s, step=bool(on), iterations=0, stalled=False)))

    def set_constraints(self, client: str, clearance: bool | None = None, balance: bool | None = None) -> dict:
        """Switch clearance (a hard Clearance(0)) and/or balance (the CoM over the feet), and re-solve."""
        return self._change(client, lambda s: self._settle(core.with_constraints(self.tree, s, clearance, balance)))

    def set_max_joint_speed(self, client: str, speed: float | None) -> dict:
        """Limit every joint's speed (rad/s, m/s; None: no limit): a StepLimit of ``speed / fps`` per frame."""
        step = None if speed is None else speed / self.fps
        return self._change(client, lambda s: self._settle(core.with_max_step(s, step)))

    def reset(self, client: str) -> dict:
        """Back to the home pose with targets on the effectors (method, goal kind and mode kept)."""
        def home(s: core.State) -> core.State:
            fresh = core.initial_state(self.tree, list(s.targets))
            return self._settle(replace(fresh, method=s.method, goal=s.goal, step=s.step, clearance=s.clearance,
                                        balance=s.balance, max_step=s.max_step))
        return self._change(client, home)

    def _settle(self, state: core.State) -> core.State:
        return state if state.step else core.solve_state(self.tree, state)

    # ------------------------------------------------------------ solutions
    def find_solutions(self, client: str) -> dict:
        """Every IK solution of the one active frame's target (at most :data:`core.MAX_SOLUTIONS`); the first shown.

        Returns the state with ``count`` and ``index`` (0; None when there are none, and ``reason`` says why).
        """
        with self._lock:
            self._claim(client)
            held, why = core.find_solutions(self.tree, self.state)
            self._solutions = held if len(held.q) else None
            reply = self.show_solution(client, 0) if len(held.q) else self.snapshot()
        return {"count": len(held.q), "index": reply.get("solutions", {}).get("index"), **reply,
                **({"reason": why} if why else {})}

    def show_solution(self, client: str, index: int | None = None) -> dict:
        """Show solution ``index`` of the list held (modulo its length; None: the next), with ``count``, ``index``."""
        def pick(s: core.State) -> core.State:
            held = self._held(s)
            if held is None:
                raise InputError("no solutions of the current target are held; POST /solutions {} finds them")
            s, self._solutions = core.show_solution(self.tree, s, held, held.index + 1 if index is None else index)
            return s
        state = self._change(client, pick)
        return {"count": state["solutions"]["count"], "index": state["solutions"]["index"], **state}

    def _held(self, state: core.State) -> core.Solutions | None:
        """The solutions list if it still solves ``state``'s target (a new target, drag or frame drops it)."""
        held = self._solutions
        return held if held is not None and held.key == core.target_key(state) else None

    # ------------------------------------------------------------ recording
    def record(self, client: str) -> dict:
        """Start recording (the pose and targets at the frame rate), journaled to the recordings folder.

        Raises:
            MjkinIOError: the journal cannot be made there.
        """
        with self._lock:
            self._claim(client)
            if self._recording is not None:
                raise InputError("already recording; POST /stop first")
            self._check_not_saving()
            if self._unsaved is not None:
                raise InputError("the last recording is not written yet; Stop & save (POST /stop) writes it")
            s = self.state
            log = Journal(journal.base_name(self.out_dir, self.tree.name or "model"), {
                "model": self.tree.name, "source": self.source, "fingerprint": motion.fingerprint(self.tree),
                "frames": list(s.targets), "method": s.method, "goal": s.goal})
            self._recording = Recording([], log, time.monotonic())
        self._wake.set()
        return self.snapshot()

    def stop(self, client: str) -> dict:
        """Stop recording and start writing the take in a save thread; its :class:`Save` report at once.

        The thread writes an mp4 (the camera at the stop) and the trajectory script (JSON) beside
        it, each atomically, then removes the journal; ``/state`` reports its ``save``. When writing
        fails (disk full, folder gone) the take is kept and ``save.error`` says so; calling again writes it.
        """
        with self._lock:
            self._claim(client)
            self._check_not_saving()
            if self._recording is not None:
                self._unsaved = Take(self._recording, self.camera, self.state)
                self._recording = None
            take = self._unsaved
            if take is None:
                raise InputError("not recording; POST /record first")
            if self.closed:
                raise InputError("the playground is shutting down; the recording is not written")
            samples, base = self._samples(take), take.recording.journal.base
            self._save = save = Save(str(base.with_name(f"{base.name}.json")), str(base.with_name(f"{base.name}.mp4")),
                                     len(samples))
            report = save.report()
            self._saver = threading.Thread(target=self._write, args=(take, samples, save), name="mjkin-play-save")
            self._saver.start()
        return report

    def _check_not_saving(self) -> None:
        save = self._save
        if save is not None and not save.finished:
            raise InputError(f"the last recording is being saved ({save.progress:.0%}); wait until /state's "
                             "\"save\" is done")

    def _samples(self, take: Take) -> list[Sample]:
        """The take's samples; a still (fewer than two) is the pose held for one frame (a script's times increase)."""
        samples = take.recording.samples
        if len(samples) >= 2:
            return samples
        first = samples[0] if samples else (0.0, take.state.q, self._points(take.state))
        return [first, (first[0] + 1.0 / self.fps, *first[1:])]

    def _write(self, take: Take, samples: list[Sample], save: Save) -> None:
        """The save thread: the video, then the script (no video without it), then the journal goes."""
        try:
            video = self._write_video(take, samples, save)
            try:
                self._script(take, samples).save(save.path)
            except BaseException:
                video.unlink(missing_ok=True)  # the retry writes both
                raise
        except Exception as e:  # any failure: the take is kept, the page says why
            save.error = " ".join(f"{e}; the recording is kept: free space or fix the folder, then Stop & save "
                                  "again (POST /stop)".split())
            return
        take.recording.journal.remove()
        with self._lock:
            self._unsaved = None
            save.progress, save.done = 1.0, True

    def _script(self, take: Take, samples: list[Sample]) -> motion.Trajectory:
        times, qs, targets = columns(samples)
        s, frames = take.state, list(take.state.targets)
        return motion.Trajectory(times=times, q=qs, fingerprint=motion.fingerprint(self.tree), model=self.tree.name,
                                 frame=frames[0], targets=targets, source=self.source,
                                 meta={"play": {"frames": frames, "method": s.method, "goal": s.goal}})

    def _write_video(self, take: Take, samples: list[Sample], save: Save) -> Path:
        """The take's mp4 at :data:`VIDEO_FPS`: the pose of each frame's time, drawn as the live view draws.

        No multisampling, shadows or reflections (:func:`live_painter`): in software GL a frame
        costs a fifth of a full-quality one.
        """
        times, qs, targets = columns(samples)
        pick = np.searchsorted(times, np.arange(0.0, times[-1] + 1e-9, 1.0 / VIDEO_FPS), side="right") - 1
        points = np.zeros((len(qs), 0, 3)) if targets is None else targets
        with live_painter(self.tree, self.width, self.height) as painter:
            painter.fit(qs)
            images = self._frames(painter, take, qs[pick], points[pick], save)
            return render.write_video(images, save.video, VIDEO_FPS)

    def _frames(self, painter: render.Painter, take: Take, qs: np.ndarray, points: np.ndarray,
                save: Save) -> Iterator[np.ndarray]:
        """Frames ``(H, W, 3)`` of poses ``qs (T, nq)``, target ``points (T, n, 3)``, the first effector's trail.

        ``save.progress`` follows (its last share: the encoder finishing, the script).
        """
        trail = self.tree.pose(qs, next(iter(take.state.targets)))[:, :3, 3]
        camera = take.camera.mjv(self.tree.model)
        for t, q in enumerate(qs):
            yield painter.draw(q, camera, points[t], trail[render.trail_indices(t, MARKERS.trail_points)], MARKERS)
            save.progress = (t + 1) / (len(qs) + 1)

    @property
    def recording(self) -> bool:
        """A recording is on."""
        return self._recording is not None

    @property
    def unsaved(self) -> bool:
        """A stopped recording could not be written yet (:meth:`stop` again writes it)."""
        return self._unsaved is not None

    # --------------------------------------------------------------- output
    def _points(self, state: core.State) -> np.ndarray:
        return np.array([np.asarray(t, float)[:3] for t in state.targets.values()]).reshape(-1, 3)

    def snapshot(self) -> dict:
        """The state as the JSON of ``GET /state``."""
        with self._lock:
            s, version, camera = self.state, self._version, self.camera
            recording, unsaved = self._recording is not None, self._unsaved is not None
            save = None if self._save is None else self._save.report()
            controller = self._controller if time.monotonic() < self._lease_until else None
            held = self._held(s)
        view = core.View.of(camera, self.tree.model, self.width, self.height)
        points = self._points(s)
        screen = view.project(points)
        rotations = spatial.quat_to_mat(np.array([np.asarray(t, float)[3:] for t in s.targets.values()]))
        tips = view.project(points[:, None, :] + AXIS_LENGTH * np.swapaxes(rotations, -1, -2))  # (n, 3, 2)
        return {"model": self.tree.name, "q": s.q.tolist(),
                "targets": {f: np.asarray(t, float).tolist() for f, t in s.targets.items()},
                "error": list(s.error), "iterations": s.iterations, "method": s.method, "goal": s.goal,
                "status": s.status, "success": s.success, "stepping": core.needs_step(s),
                "singular_values": list(s.singular), "manipulability": s.manipulability, "step": s.step,
                "recording": recording, "unsaved": unsaved, "save": save, "controlled": controller is not None,
                "version": version,
                "screen": {f: uv.tolist() for f, uv in zip(s.targets, screen, strict=True)},
                "screen_axes": {f: uv.tolist() for f, uv in zip(s.targets, tips, strict=True)},
                "camera": {"lookat": list(camera.lookat), "distance": camera.distance, "azimuth": camera.azimuth,
                           "elevation": camera.elevation}, **core.constraint_report(self.tree, s),
                "max_joint_speed": None if s.max_step is None else s.max_step * self.fps,
                **({} if held is None else {"solutions": {"count": len(held.q), "index": held.index}})}

    def info(self) -> dict:
        """What the page needs once: methods, goal kinds, frames, sliders, image size."""
        return {"model": self.tree.name, "methods": list(core.panel_methods()), "goals": list(core.goal_kinds()),
                "sites": [n for n in self.tree.names("site") if n],
                "bodies": [n for n in self.tree.names("body")[1:] if n],
                "joints": core.joint_sliders(self.tree), "width": self.width, "height": self.height,
                "lease": self.lease, "fps": self.fps, "balance": core.balance_available(self.tree) is None,
                "support": core.support_frames(self.tree)}

    def frame(self, after: int = -1, timeout: float = 5.0) -> tuple[int, bytes]:
        """The first frame numbered above ``after`` that shows the state as of this call: ``(number, jpeg)``.

        Waits for the render thread; raises :class:`MjkinError` when it stops or times out.
        """
        deadline, want = time.monotonic() + timeout, self._version  # the state as of this request
        with self._frame_ready:
            while True:
                if self._error is not None:
                    raise MjkinError(f"rendering failed: {self._error}")
                version, number, jpeg = self._frame
                if number > after and version >= want:
                    return number, jpeg
                left = deadline - time.monotonic()
                if self.closed or left <= 0:
                    raise MjkinError("no frame: the playground is shutting down" if self.closed
                                     else "no frame within the time limit")
                self._frame_ready.wait(left)

    def next_frame(self, after: int, timeout: float = 1.0) -> tuple[int, bytes] | None:
        """For streams: the first frame numbered above ``after``, or None after ``timeout`` or at shutdown."""
        with self._frame_ready:
            self._frame_ready.wait_for(lambda: self._frame[1] > after or self.closed, timeout)
            if self.closed or self._frame[1] <= after:
                return None
            return self._frame[1], self._frame[2]

    # --------------------------------------------------------- render thread
    def _render_loop(self) -> None:
        trail: deque[np.ndarray] = deque(maxlen=TRAIL)
        shown, number, period = -1, 0, 1.0 / self.fps
        try:
            painter = live_painter(self.tree, self.width, self.height)
        except BaseException as e:  # no GL: requests report it instead of hanging
            self._fail(e)
            return
        try:
            while not self.closed:
                tick = time.monotonic()
                with self._lock:
                    if core.needs_step(self.state):
                        self.state = core.advance(self.tree, self.state)
                        self._version += 1
                    state, version, camera = self.state, self._version, self.camera
                    if self._recording is not None:
                        sample = (tick - self._recording.start, state.q.copy(), self._points(state))
                        self._recording.samples.append(sample)
                        self._recording.journal.add(sample)
                    busy = core.needs_step(state) or self._recording is not None
                if version != shown:
                    tip = self.tree.pose(state.q, next(iter(state.targets)))[:3, 3]
                    if not trail or np.linalg.norm(tip - trail[-1]) >= TRAIL_STEP:
                        trail.append(tip)
                    image = painter.draw(state.q, camera.mjv(self.tree.model), self._points(state), np.array(trail),
                                         MARKERS, lines=core.constraint_lines(self.tree, state))
                    jpeg = encode_jpeg(image)
                    number += 1
                    with self._frame_ready:
                        self._frame = (version, number, jpeg)
                    self._notify()
                    shown = version
                if busy:
                    self._closed.wait(max(0.0, period - (time.monotonic() - tick)))
                else:
                    self._wake.wait(1.0)
                    self._wake.clear()
        except BaseException as e:
            self._fail(e)
        finally:
            painter.close()

    def _fail(self, e: BaseException) -> None:
        with self._frame_ready:
            self._error = e
        self._notify()
