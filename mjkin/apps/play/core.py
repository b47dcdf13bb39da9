"""The playground's core as pure functions: the orbit camera, rays, a drag on the view plane, the warm-started solve.

``(state, event) → targets → IK → q``: :func:`move` turns a drag, a push in depth
or a placed target into new targets; :func:`solve_state` runs the chosen IK method
from the current pose (warm start, no random restarts, so the figure follows
continuously and stays inside its joint limits). ``(camera, view event) → camera``:
:func:`look` orbits, zooms or resets the camera; the :class:`View` that drags use is
built from the camera of the moment. Nothing here touches a socket,
a thread or a GL context, so all of it is tested without a browser.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ... import goals as G
from ... import spatial
from ...errors import InputError
from ...explore.solutions import solutions
from ...goals import registry
from ...goals.clearance import bounded_geoms
from ...ik import METHODS, Problem
from ...kinematics.distance import pair_distance
from ...kinematics.frames import forward
from ...kinematics.geoms import contact_pairs, native_pairs
from ...kinematics.qspace import FREE, HINGE, SLIDE
from ...kinematics.tree import Tree

Array = NDArray[np.float64]

AUTO_ITERS = 200  # auto follows without restarts, so it gets more iterations than its 50 per restart
# targets farther than FAR model extents from the model's centre are refused (Tree.check_near): no figure reaches
# them, and at ~1e154 m the position error overflows (every panel method still gives finite results at FAR)


# ---------------------------------------------------------------------- camera
ELEVATION_LIMIT = 89.0  # degrees: the orbit stops short of the poles, where "up" and the azimuth lose their meaning
# zoom keeps the distance within these multiples of the initial framing's: nearer, the camera would enter the space
# the figure reaches and a target could fall behind it (tested on arm7: from any side, at the nearest, every point
# the effector reaches stays in front of the camera)
DISTANCE_RANGE = (0.5, 4.0)


@dataclass(frozen=True)
class Camera:
    """A free camera on a sphere about ``lookat`` (world, m): ``distance`` (m), ``azimuth`` and ``elevation`` (deg).

    MuJoCo's free-camera convention (:class:`mujoco.MjvCamera`): the azimuth turns
    about world z from +x, a negative elevation looks down.
    """

    lookat: tuple[float, float, float]
    distance: float
    azimuth: float
    elevation: float

    @classmethod
    def of(cls, cam: mujoco.MjvCamera) -> Camera:
        """The orbit camera of a MuJoCo free camera, its elevation clamped to ±:data:`ELEVATION_LIMIT`.

        (A planar chain is framed from straight above, at -90°.)
        """
        x, y, z = (float(v) for v in cam.lookat)
        elevation = float(np.clip(cam.elevation, -ELEVATION_LIMIT, ELEVATION_LIMIT))
        return cls((x, y, z), float(cam.distance), float(cam.azimuth), elevation)

    def mjv(self, model: mujoco.MjModel) -> mujoco.MjvCamera:
        """This camera as a MuJoCo free camera, for the renderer."""
        cam = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(model, cam)
        cam.lookat[:] = self.lookat
        cam.distance, cam.azimuth, cam.elevation = self.distance, self.azimuth, self.elevation
        return cam


@dataclass(frozen=True)
class View:
    """A pinhole camera: ``pos (3,)``, unit ``forward`` and ``up`` (world), vertical ``fovy`` (degrees), ``aspect``.

    Image points ``uv`` are fractions of the image, ``(0, 0)`` the top-left corner,
    ``(1, 1)`` the bottom-right, as the page measures a mouse position.
    """

    pos: Array
    forward: Array
    up: Array
    fovy: float
    aspect: float

    @classmethod
    def of(cls, cam: mujoco.MjvCamera | Camera, model: mujoco.MjModel, width: int, height: int) -> View:
        """The view of a free camera (``lookat``, ``distance``, ``azimuth``, ``elevation``) in an image."""
        az, el = np.radians(cam.azimuth), np.radians(cam.elevation)
        forward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        up = np.array([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)])
        pos = np.asarray(cam.lookat, float) - cam.distance * forward
        return cls(pos, forward, up, float(model.vis.global_.fovy), width / height)

    @property
    def right(self) -> Array:
        """Unit vector to the right of the image, ``(3,)``."""
        return np.cross(self.forward, self.up)

    def ray(self, uv: ArrayLike) -> Array:
        """Unit directions ``(..., 3)`` from :attr:`pos` through image points ``uv (..., 2)``."""
        uv = np.asarray(uv, float)
        t = np.tan(np.radians(self.fovy) / 2)
        x = (2 * uv[..., :1] - 1) * t * self.aspect
        y = (1 - 2 * uv[..., 1:2]) * t
        d = self.forward + x * self.right + y * self.up
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project(self, points: ArrayLike) -> Array:
        """Image points ``(..., 2)`` of world ``points (..., 3)`` (in front of the camera; level with it: inf, NaN)."""
        rel = np.asarray(points, float) - self.pos
        z = rel @ self.forward
        t = np.tan(np.radians(self.fovy) / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (rel @ self.right) / (z * t * self.aspect)
            y = (rel @ self.up) / (z * t)
        return np.stack([(x + 1) / 2, (1 - y) / 2], axis=-1)


def drag(view: View, target: ArrayLike, uv: ArrayLike) -> Array:
    """Where the ray through ``uv`` meets the plane facing the camera through ``target``: the dragged point ``(3,)``."""
    target = np.asarray(target, float)
    d = view.ray(uv)
    along = float(d @ view.forward)
    if along <= 1e-9:  # the ray runs along the plane: stay put
        return target.copy()
    return view.pos + d * float((target - view.pos) @ view.forward) / along


def push(view: View, target: ArrayLike, amount: float) -> Array:
    """``target`` moved ``amount`` metres along the line of sight (positive: away from the camera), ``(3,)``."""
    target = np.asarray(target, float)
    d = target - view.pos
    return target + float(amount) * d / max(float(np.linalg.norm(d)), 1e-12)


# ----------------------------------------------------------------------- state
@dataclass(frozen=True)
class State:
    """What the playground shows: the pose ``q (nq,)``, one target per effector frame, how it is solved.

    ``targets`` maps a site or body name to ``[x, y, z, qw, qx, qy, qz]`` (world).
    ``error`` is the worst ``[position (m), rotation (rad)]`` error of the last
    solve; ``singular`` the singular values of the goals' Jacobian at ``q``
    (their product is the manipulability). ``clearance``, ``balance`` and ``max_step``
    (the most any joint moves per frame: rad, m) add hard constraints to every solve
    (:func:`constraint_goals`); with ``max_step`` the figure moves toward a far target
    frame by frame, as in step mode.
    """

    q: Array
    targets: Mapping[str, Array]
    method: str = "auto"
    goal: str = "position"
    step: bool = False
    error: tuple[float, float] = (0.0, 0.0)
    iterations: int = 0
    status: str = "converged"
    success: bool = True
    singular: tuple[float, ...] = ()
    stalled: bool = field(default=False, repr=False)
    clearance: bool = False
    balance: bool = False
    max_step: float | None = None

    @property
    def manipulability(self) -> float:
        """Yoshikawa's manipulability, the product of :attr:`singular` (0 at a singularity)."""
        return float(np.prod(self.singular)) if self.singular else 0.0


@dataclass(frozen=True)
class Drag:
    """Move ``frame``'s target to image point ``uv`` on the plane facing the camera through the target."""

    frame: str
    uv: tuple[float, float]


@dataclass(frozen=True)
class Push:
    """Move ``frame``'s target ``amount`` metres along the line of sight (the wheel)."""

    frame: str
    amount: float


@dataclass(frozen=True)
class Turn:
    """Turn ``frame``'s target ``angle`` radians about the line of sight (counter-clockwise as seen; pose goals)."""

    frame: str
    angle: float


@dataclass(frozen=True)
class Place:
    """Put ``frame``'s target at ``pos (3,)``, turned to ``quat (4,)`` when given."""

    frame: str
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float] | None = None


Event = Drag | Push | Turn | Place


@dataclass(frozen=True)
class Orbit:
    """Turn the camera about its look-at point: ``azimuth`` and ``elevation`` changes in degrees."""

    azimuth: float
    elevation: float


@dataclass(frozen=True)
class Zoom:
    """Scale the camera's distance to its look-at point by ``factor`` (below 1: closer)."""

    factor: float


@dataclass(frozen=True)
class ResetView:
    """Back to the initial camera."""


ViewEvent = Orbit | Zoom | ResetView


def distance_range(home: Camera) -> tuple[float, float]:
    """The distances (m) zoom keeps to: :data:`DISTANCE_RANGE` times ``home``'s."""
    return DISTANCE_RANGE[0] * home.distance, DISTANCE_RANGE[1] * home.distance


def look(home: Camera, camera: Camera, event: ViewEvent) -> Camera:
    """The camera after an orbit, a zoom or a view reset; the look-at point stays put.

    The elevation is clamped to ±:data:`ELEVATION_LIMIT`, the azimuth kept in
    [-180, 180], the distance in :func:`distance_range` of ``home`` (the initial camera).
    """
    if isinstance(event, Orbit):
        turn = (event.azimuth, event.elevation)
        if not np.isfinite(turn).all():
            raise InputError(f"an orbit needs finite angles [d_azimuth, d_elevation] in degrees, got {list(turn)!r}")
        azimuth = (camera.azimuth + float(event.azimuth) + 180.0) % 360.0 - 180.0
        elevation = float(np.clip(camera.elevation + float(event.elevation), -ELEVATION_LIMIT, ELEVATION_LIMIT))
        return replace(camera, azimuth=azimuth, elevation=elevation)
    if isinstance(event, Zoom):
        if not (np.isfinite(event.factor) and event.factor > 0):
            raise InputError(f"a zoom needs a finite factor > 0 (below 1: closer), got {event.factor!r}")
        lo, hi = distance_range(home)
        return replace(camera, distance=float(np.clip(camera.distance * float(event.factor), lo, hi)))
    return home


def default_frames(tree: Tree) -> list[str]:
    """The effectors a model starts with: its sites on leaf bodies (hands, feet, a flange), else its leaf bodies."""
    parents = set(tree.body_parent[1:].tolist())
    leaves = [b for b in range(1, tree.nbody) if b not in parents]
    sites = [n for i, n in enumerate(tree.names("site")) if n and int(tree.site_body[i]) in leaves]
    bodies = [tree.names("body")[b] for b in leaves if tree.names("body")[b]]
    return sites or bodies[-1:] or [tree.names("body")[-1]]


def frame_target(tree: Tree, q: Array, frame: str) -> Array:
    """``[x, y, z, qw, qx, qy, qz]`` of ``frame`` at ``q``: a target the frame already meets."""
    T = tree.pose(q, frame)
    return np.concatenate([T[:3, 3], spatial.mat_to_quat(T[:3, :3])])


def initial_state(tree: Tree, frames: Sequence[str] | None = None, method: str = "auto") -> State:
    """The first keyframe (else ``qpos0``), with targets where the effector frames are."""
    q = tree.model.key_qpos[0].copy() if tree.model.nkey else tree.qpos0.copy()
    state = State(q=tree.clip(q), targets={}, method=method)
    return with_frames(tree, state, default_frames(tree) if frames is None else frames)


def with_frames(tree: Tree, state: State, frames: Sequence[str]) -> State:
    """The same state with these effector frames; new ones get a target where they are now."""
    if not frames:
        raise InputError("choose at least one effector frame (a site or body)")
    for f in frames:
        tree.frame(f)  # UnknownNameError lists the sites and bodies
    targets = {f: state.targets[f] if f in state.targets else frame_target(tree, state.q, f) for f in frames}
    return replace(state, targets=targets, iterations=0, stalled=False)


def panel_methods() -> tuple[str, ...]:
    """The IK methods the panel offers: every registered one (:data:`mjkin.ik.METHODS`) that is
    :meth:`~mjkin.ik.Method.iterative`, so it follows a drag from the current pose and step mode can step it.
    """  # noqa: D205
    return tuple(name for name, method in METHODS.items() if method.iterative())


def goal_kinds() -> dict[str, Callable[[str, Array, Array], G.Goal]]:
    """The goal kinds the panel offers, by lower-case class name (``position``, ``pose``, ``aim``, ...).

    Every registered kind (:data:`mjkin.goals.registry.KINDS`) with a class method ``from_target(frame, xyz, quat)``
    that makes it from a placed target (a point ``(3,)`` and a quaternion ``(4,)``, world), mapped to that method.
    """
    return {kind.__name__.lower(): kind.from_target for kind in registry.KINDS if hasattr(kind, "from_target")}


def with_method(state: State, method: str) -> State:
    """The same state solved by another method (one of :func:`panel_methods`)."""
    if method not in (offered := panel_methods()):
        raise InputError(f"unknown method {method!r}; choose one of: {', '.join(offered)}")
    return replace(state, method=method, iterations=0, stalled=False)


def with_goal(state: State, goal: str) -> State:
    """The same state with another goal kind (one of :func:`goal_kinds`: ``position``, ``pose``, ``aim``, ...)."""
    if goal not in (offered := goal_kinds()):
        raise InputError(f"unknown goal kind {goal!r}; choose one of: {', '.join(offered)}")
    return pending(replace(state, goal=goal))


def with_joint(tree: Tree, state: State, joint: str, value: float) -> State:
    """Forward kinematics: set one hinge or slide joint (clipped to its range); the targets follow the frames.

    A slide that would take a frame beyond :data:`mjkin.kinematics.tree.FAR` model extents is refused.
    """
    j = tree.id(joint, "joint")
    if int(tree.jnt_type[j]) not in (HINGE, SLIDE):
        raise InputError(f"joint {joint!r} is a ball or free joint; sliders move hinge and slide joints only")
    if not np.isfinite(value):
        raise InputError(f"joint value must be a finite number, got {value!r}")
    q = state.q.copy()
    q[tree.jnt_qadr[j]] = value
    q = tree.clip(q)
    targets = {f: frame_target(tree, q, f) for f in state.targets}
    for f, t in targets.items():
        tree.check_near(t[:3], f"the target of {f!r}")
    return replace(state, q=q, targets=targets, error=(0.0, 0.0), iterations=0, status="converged",
                   success=True, stalled=False)


def move(tree: Tree, view: View, state: State, event: Event) -> State:
    """New targets after a drag, a push, a turn or a placement (``q`` unchanged); none too far (``Tree.check_near``)."""
    if event.frame not in state.targets:
        tree.frame(event.frame)  # an unknown name: the error lists the names that exist
        state = with_frames(tree, state, [*state.targets, event.frame])
    old = np.asarray(state.targets[event.frame], float)
    new = old.copy()
    if isinstance(event, Drag):
        uv = np.asarray(event.uv, float)
        if uv.shape != (2,) or not np.isfinite(uv).all():
            raise InputError(f"a drag needs image coordinates [u, v] (fractions of the image), got {event.uv!r}")
        new[:3] = drag(view, old[:3], uv)
    elif isinstance(event, Push):
        if not np.isfinite(event.amount):
            raise InputError(f"a push needs a finite distance in metres, got {event.amount!r}")
        new[:3] = push(view, old[:3], event.amount)
    elif isinstance(event, Turn):
        if not np.isfinite(event.angle):
            raise InputError(f"a turn needs a finite angle in radians, got {event.angle!r}")
        new[3:] = spatial.quat_mul(spatial.quat_from_axis_angle(-view.forward, event.angle), old[3:])
    else:
        pos = np.asarray(event.pos, float)
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise InputError(f"pos must be 3 finite numbers [x, y, z] (metres), got {event.pos!r}")
        new[:3] = pos
        if event.quat is not None:
            quat = np.asarray(event.quat, float)
            if quat.shape != (4,) or not np.isfinite(quat).all() or np.abs(quat).max() < 1e-9:
                raise InputError(f"quat must be 4 finite numbers [w, x, y, z], not all zero, got {event.quat!r}")
            quat = quat / np.abs(quat).max()  # first to ~1: the norm of [1e308, 0, 0, 1e308] would overflow
            new[3:] = quat / np.linalg.norm(quat)
    tree.check_near(new[:3], f"the target of {event.frame!r}")
    return pending(replace(state, targets={**state.targets, event.frame: new}))


def pending(state: State) -> State:
    """The state with goals not yet solved (step mode then has work to do)."""
    return replace(state, success=False, status="pending", iterations=0, stalled=False)


def goals_for(state: State) -> list[G.Goal]:
    """The IK goals of the targets for the state's goal kind (made by its ``from_target``)."""
    make = goal_kinds()[state.goal]
    targets = {frame: np.asarray(t, float) for frame, t in state.targets.items()}
    return [make(frame, t[:3], t[3:]) for frame, t in targets.items()]


# ----------------------------------------------------------------- constraints
def support_frames(tree: Tree) -> list[str]:
    """The frames balance stands on: the sites named for feet (``*foot*``), else the bodies; none on an arm."""
    sites = [n for n in tree.names("site") if n and "foot" in n]
    return sites or [n for n in tree.names("body") if n and "foot" in n]


def balance_available(tree: Tree) -> str | None:
    """Why balance cannot be switched on for ``tree`` (None: it can)."""
    if len(support_frames(tree)) < 2:
        return f"balance needs two or more feet (sites or bodies named *foot*); {tree.name!r} has none"
    return None


def constraint_goals(tree: Tree, state: State) -> list[G.Goal]:
    """The hard goals the toggles add: ``Clearance(0)`` (every pair MuJoCo would collide) and
    ``CenterOfMass(support=feet)`` (the CoM over the feet's polygon); ``StepLimit(q, max_step)`` from this frame.
    """  # noqa: D205
    out: list[G.Goal] = [G.Clearance(0.0)] if state.clearance else []
    if state.balance:
        out.append(G.Balance(support_frames(tree)))
    if state.max_step is not None:
        out.append(G.StepLimit(state.q, state.max_step))
    return out


def with_max_step(state: State, max_step: float | None) -> State:
    """The state with a per-frame joint step limit (rad, m; None: none).

    Raises:
        InputError: not a positive finite number.
    """
    if max_step is not None and not (isinstance(max_step, (int, float)) and 0 < max_step < math.inf):
        raise InputError(f"the joint speed limit must be a positive number (or null: none), got {max_step!r}")
    return replace(state, max_step=None if max_step is None else float(max_step), iterations=0, stalled=False)


def with_constraints(tree: Tree, state: State, clearance: bool | None = None, balance: bool | None = None) -> State:
    """The state with clearance and/or balance switched (None: unchanged).

    Raises:
        InputError: balance asked of a model without feet (or of a build without CenterOfMass).
    """
    if balance and (why := balance_available(tree)) is not None:
        raise InputError(why)
    return replace(state, clearance=state.clearance if clearance is None else bool(clearance),
                   balance=state.balance if balance is None else bool(balance), iterations=0, stalled=False)


@dataclass(frozen=True)
class Closest:
    """The closest geom pair at a pose: its names, signed distance (m) and witness points ``a``, ``b`` (world)."""

    geoms: tuple[str, str]
    distance: float
    a: Array
    b: Array


def closest_pair(tree: Tree, q: Array) -> Closest | None:
    """The pair of MuJoCo's contact pairs nearest each other at ``q (nq,)``, as Clearance measures it (None: no pairs).

    mjkin's distances and witness points (a pair mjkin cannot measure with its geom's bounding
    sphere, as :class:`~mjkin.goals.Clearance` takes it).
    """
    pairs = contact_pairs(tree)
    if not len(pairs):
        return None
    bounded, native = bounded_geoms(tree.geoms, pairs), native_pairs(tree.geoms, pairs)
    f = forward(tree, np.asarray(q, float).reshape(1, -1))
    a, b = np.empty(3), np.empty(3)
    best, where = np.inf, (np.zeros(3), np.zeros(3), 0)
    for k, (g1, g2) in enumerate(pairs):
        d = pair_distance(tree.geoms if native[k] else bounded, f.rot, f.pos, int(g1), int(g2), a, b)
        if d < best:
            best, where = d, (a.copy(), b.copy(), k)
    g1, g2 = (int(g) for g in pairs[where[2]])
    name = tree.model.geom
    return Closest((name(g1).name or f"#{g1}", name(g2).name or f"#{g2}"), float(best), where[0], where[1])


@dataclass(frozen=True)
class Support:
    """Balance at a pose: the support polygon's corners ``(K, 3)`` on the ground (counter-clockwise) and the CoM's
    ground point ``(3,)``, with whether it lies inside.
    """  # noqa: D205

    polygon: Array
    com: Array
    inside: bool


def support(tree: Tree, q: Array, frames: Sequence[str] | None = None) -> Support:
    """The convex hull of the feet's support points (their soles, as balance takes them) and the CoM, both dropped
    to the lowest point's height (z up).
    """  # noqa: D205
    pts = G.Balance(support_frames(tree) if frames is None else list(frames)).points(tree, q)
    com = np.asarray(tree.com(q), float).reshape(3)
    ground = float(pts[:, 2].min())
    hull = convex_hull(pts[:, :2])
    polygon = np.column_stack([hull, np.full(len(hull), ground)])
    inside = len(hull) >= 3 and bool(np.all(cross2(np.roll(hull, -1, 0) - hull, com[:2] - hull) >= -1e-9))
    return Support(polygon, np.array([com[0], com[1], ground]), inside)


def cross2(a: ArrayLike, b: ArrayLike) -> Array:
    """The z of the cross product of 2-D vectors ``(..., 2)``: > 0 when ``b`` turns counter-clockwise from ``a``."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


STRAIGHT = 1e-12  # convex_hull drops a corner this close (x the points' extent) to the edge its neighbours make


def convex_hull(points: Array) -> Array:
    """The convex hull of ``points (n, 2)``, counter-clockwise (Andrew's monotone chain), ``(k, 2)``.

    A corner within :data:`STRAIGHT` times the points' extent of the segment between its
    neighbours (a point on an edge but for rounding, or next to another corner) is left
    out, so every corner turns left by more than rounding, as computed from its edges too.
    """
    arr = np.asarray(points, float).reshape(-1, 2)
    pts = sorted(map(tuple, arr))
    if len(pts) < 3:
        return np.array(pts).reshape(-1, 2)

    def half(seq: list) -> list:
        out: list = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out

    hull = half(pts)[:-1] + half(pts[::-1])[:-1]
    tol = STRAIGHT * float(np.ptp(arr, axis=0).max())
    while len(hull) >= 3:
        near = next((i for i in range(len(hull))
                     if _off_segment(hull[i - 1], hull[i], hull[(i + 1) % len(hull)]) <= tol), None)
        if near is None:
            break
        del hull[near]
    return np.array(hull).reshape(-1, 2)


def _off_segment(o: tuple, a: tuple, b: tuple) -> float:
    """How far the point ``a`` is from the segment ``o``–``b`` (2-D)."""
    dx, dy = b[0] - o[0], b[1] - o[1]
    ax, ay = a[0] - o[0], a[1] - o[1]
    length2 = dx * dx + dy * dy
    t = min(max((ax * dx + ay * dy) / length2, 0.0), 1.0) if length2 > 0 else 0.0
    return math.hypot(ax - t * dx, ay - t * dy)


CLEAR_RGBA = (0.1, 0.8, 0.3, 1.0)  # the closest pair's line when apart; red when touching
TOUCH_RGBA = (0.95, 0.1, 0.1, 1.0)
SUPPORT_RGBA = (0.95, 0.75, 0.1, 1.0)


def constraint_lines(tree: Tree, state: State) -> list[tuple[Array, tuple[float, float, float, float]]]:
    """What the toggles draw: the closest pair between its witness points (clearance), the support polygon and a
    drop line from the CoM to its ground point (balance; green inside, red outside).
    """  # noqa: D205
    out: list[tuple[Array, tuple[float, float, float, float]]] = []
    if state.clearance and (c := closest_pair(tree, state.q)) is not None:
        out.append((np.array([c.a, c.b]), CLEAR_RGBA if c.distance > 0 else TOUCH_RGBA))
    if state.balance:
        s = support(tree, state.q)
        out.append((np.vstack([s.polygon, s.polygon[:1]]), SUPPORT_RGBA))
        com = np.asarray(tree.com(state.q), float).reshape(3)
        out.append((np.array([com, s.com]), CLEAR_RGBA if s.inside else TOUCH_RGBA))
    return out


def constraint_report(tree: Tree, state: State) -> dict:
    """The toggles and what they measure, for ``/state``: ``closest`` (clearance on) and ``support`` (balance on)."""
    out: dict[str, Any] = {"clearance": state.clearance, "balance": state.balance, "closest": None, "support": None}
    if state.clearance and (c := closest_pair(tree, state.q)) is not None:
        out["closest"] = {"geoms": list(c.geoms), "distance": c.distance, "a": c.a.tolist(), "b": c.b.tolist()}
    if state.balance:
        s = support(tree, state.q)
        out["support"] = {"polygon": s.polygon.tolist(), "com": s.com.tolist(), "inside": s.inside}
    return out


def movable_joints(tree: Tree) -> list[str] | None:
    """Joints IK may move: all but free joints (a free-floating figure keeps its root where it stands)."""
    names = tree.names("joint")
    free = tree.jnt_type == FREE
    if not free.any() or free.all() or not all(names):
        return None
    return [n for n, f in zip(names, free, strict=True) if not f]


_PROBLEMS: dict[tuple, Problem] = {}  # the playground's IK problems, by tree, goal structure, method and budget


def problem_for(tree: Tree, goals: list[G.Goal], method: str, iters: int | None) -> Problem:
    """The :class:`~mjkin.Problem` for these goals' structure (made at its first use, then kept; at most 64)."""
    key = (id(tree), tuple(g.key() for g in goals), method, iters)
    problem = _PROBLEMS.get(key)
    if problem is None or problem.tree is not tree:
        if len(_PROBLEMS) >= 64:
            _PROBLEMS.clear()
        options: dict[str, Any] = {} if iters is None else {"max_iters": iters}
        problem = Problem(tree, goals, method=method, restarts=0, joints=movable_joints(tree), **options)
        _PROBLEMS[key] = problem
    return problem


def solve_state(tree: Tree, state: State, max_iters: int | None = None) -> State:
    """Solve the targets from ``state.q`` (warm start, no restarts); ``max_iters=1`` is one step of step mode."""
    method = "lm" if state.method == "auto" and max_iters is not None else state.method
    iters = AUTO_ITERS if state.method == "auto" and max_iters is None else max_iters
    goals = goals_for(state) + constraint_goals(tree, state)
    res = problem_for(tree, goals, method, iters).solve(state.q, goals)
    q = np.asarray(res.q, float)
    stepped = state.iterations + int(res.iterations) if max_iters is not None else int(res.iterations)
    limited = max_iters is not None or state.max_step is not None
    stalled = limited and float(np.abs(q - state.q).max(initial=0.0)) < 1e-12
    return replace(state, q=q, error=(float(res.error[0]), float(res.error[1])), iterations=stepped,
                   status=str(res.status), success=bool(res.success),
                   singular=tuple(float(s) for s in np.atleast_1d(res.singular_values())), stalled=stalled)


def apply(tree: Tree, view: View, state: State, event: Event) -> State:
    """The whole step: the event moves a target, IK follows from the current pose (in step mode, frame by frame)."""
    moved = move(tree, view, state, event)
    return moved if moved.step else solve_state(tree, moved)


def needs_step(state: State) -> bool:
    """Step mode (or a joint speed limit) has work to do: not yet on target and still moving."""
    return (state.step or state.max_step is not None) and not state.success and not state.stalled


def advance(tree: Tree, state: State) -> State:
    """One frame's work: a solver iteration in step mode, else a solve limited to the frame's step."""
    return solve_state(tree, state, max_iters=1 if state.step else None)


def joint_sliders(tree: Tree) -> list[dict]:
    """The hinge and slide joints as sliders: ``{"name", "qadr", "min", "max"}`` (unlimited: ±π, ±extent)."""
    out = []
    extent = float(tree.model.stat.extent) or 1.0
    for j, name in enumerate(tree.names("joint")):
        kind = int(tree.jnt_type[j])
        if kind not in (HINGE, SLIDE) or not name:
            continue
        lo, hi = tree.jnt_range[j] if tree.jnt_limited[j] else ((-np.pi, np.pi) if kind == HINGE
                                                               else (-extent, extent))
        out.append({"name": name, "qadr": int(tree.jnt_qadr[j]), "min": float(lo), "max": float(hi)})
    return out


# ------------------------------------------------------------------- solutions
MAX_SOLUTIONS = 16  # the most the playground asks :func:`mjkin.solutions` for (a 7-DoF arm's spread is bounded)


@dataclass(frozen=True)
class Solutions:
    """Every IK solution of one target: ``q (k, nq)``, the one shown, and the target they solve (:func:`target_key`)."""

    key: tuple
    q: Array
    index: int = 0


def target_key(state: State) -> tuple:
    """What a solutions list solves: the goal kind and each frame's target (a new target or drag changes it)."""
    return state.goal, tuple((f, tuple(np.asarray(t, float).tolist())) for f, t in state.targets.items())


def find_solutions(tree: Tree, state: State, max_solutions: int = MAX_SOLUTIONS) -> tuple[Solutions, str]:
    """The distinct solutions of the state's one target (constraints not applied) and, when there are none, why.

    Raises:
        InputError: several frames are active (solutions take one frame).
    """
    if len(state.targets) != 1:
        raise InputError(f"solutions take one frame; {len(state.targets)} are active ({', '.join(state.targets)}): "
                         "choose one (POST /frames)")
    res = solutions(tree, goals_for(state), max_solutions=max_solutions, joints=movable_joints(tree))
    why = "" if len(res.q) or res.reason is None else str(res.reason)
    return Solutions(target_key(state), np.asarray(res.q, float).reshape(-1, tree.nq)), why


def show_solution(tree: Tree, state: State, held: Solutions, index: int) -> tuple[State, Solutions]:
    """Solution ``index`` (modulo their number) as the pose, solved from there (its error, singular values)."""
    i = index % len(held.q)
    shown = solve_state(tree, replace(state, q=held.q[i].copy(), step=False))
    return replace(shown, step=state.step), replace(held, index=i)
