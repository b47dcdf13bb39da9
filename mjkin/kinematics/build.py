"""Making chains and trees in code, written out as MJCF that :func:`mjkin.load` accepts.

Three ways in, each giving an XML string with visible capsule links, a site
at every link tip (``<link>_tip``) and an end-effector site ``ee``:

* :func:`links_mjcf` — the seeds' axis–position records: each link points at
  its parent, names its joint kind, axis and limits, and extends ``length``
  along ``direction`` from where it is attached (by default the parent's tip);
* :func:`planar_chain` — an n-link arm in the x–y plane, hinges about z;
* :func:`dh_chain` — a Denavit–Hartenberg table ``(a, alpha, d, theta)`` per
  joint, standard or modified (Craig) convention; :func:`dh_fk` is the same
  table's forward kinematics in plain numpy, for checking.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import spatial
from ..errors import InputError
from ..runtime.checks import check_array, check_choice, check_number, check_vector

Array = NDArray[np.float64]
Vec3 = tuple[float, float, float]

JOINT_KINDS = ("hinge", "slide", "ball", "fixed")
_COLOURS = ("0.25 0.45 0.8 1", "0.3 0.65 0.45 1", "0.85 0.6 0.2 1", "0.6 0.35 0.7 1")


@dataclass(frozen=True)
class Link:
    """One rigid link and the joint that attaches it to its parent.

    Attributes:
        name: body name (unique).
        parent: name of the parent link; ``None`` attaches it to the world.
        joint: ``"hinge"``, ``"slide"``, ``"ball"`` or ``"fixed"``.
        axis: joint axis ``(3,)`` in the parent frame (the link frame is parallel to it at q = 0).
        length: link length in metres, measured along ``direction``.
        direction: unit vector ``(3,)`` along which the link extends, parent frame.
        at: attachment point in the parent frame; ``None`` = the parent's tip (the world origin for roots).
        range: ``(lo, hi)`` limits for hinge/slide, ``(0, max angle)`` for ball; ``None`` = unlimited.
        radius: capsule radius; ``None`` = 4 % of the length.
    """

    name: str
    parent: str | None = None
    joint: str = "hinge"
    axis: Vec3 = (0.0, 0.0, 1.0)
    length: float = 1.0
    direction: Vec3 = (1.0, 0.0, 0.0)
    at: Vec3 | None = None
    range: tuple[float, float] | None = None
    radius: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"a link's name must be a non-empty string, got {self.name!r:.40}")
        if self.parent is not None and not isinstance(self.parent, str):
            raise InputError(f"link {self.name!r}: parent must be a link's name or None, got {self.parent!r:.40}")
        check_choice(self.joint, f"link {self.name!r} joint", JOINT_KINDS)
        check_number(self.length, f"link {self.name!r} length")
        if self.radius is not None:
            check_number(self.radius, f"link {self.name!r} radius", 0.0, strict=True)


def _num(x: ArrayLike) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(x))


def _document(name: str, extent: float) -> tuple[ET.Element, ET.Element]:
    root = ET.Element("mujoco", model=name)
    ET.SubElement(root, "compiler", angle="radian")
    visual = ET.SubElement(root, "visual")
    ET.SubElement(visual, "global", offwidth="1280", offheight="960")
    ET.SubElement(root, "statistic", extent=_num(extent), center="0 0 0")
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "light", pos=_num([0, 0, 3 * extent]), dir="0 0 -1", directional="true")
    ET.SubElement(world, "geom", name="floor", type="plane", size=_num([2 * extent, 2 * extent, 0.1]),
                  pos=_num([0, 0, -0.1 * extent]), rgba="0.85 0.85 0.82 1", contype="0", conaffinity="0")
    return root, world


def _to_string(root: ET.Element) -> str:
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def _unit(v: ArrayLike, what: str) -> Array:
    a = check_array(v, what)
    n = float(np.linalg.norm(a)) if a.shape == (3,) and np.all(np.isfinite(a)) else 0.0
    if n < 1e-12:
        raise InputError(f"{what} must be a non-zero finite 3-vector, got {v!r}")
    return a / n


def links_mjcf(links: Sequence[Link], name: str = "chain", ee: str | None = None) -> str:
    """MJCF for a chain or tree of :class:`Link` records (parents listed before children).

    The end-effector site ``ee`` is at the tip of link ``ee`` (default: the last link).
    """
    if not isinstance(links, list | tuple) or not all(isinstance(lk, Link) for lk in links):
        raise InputError(f"links must be a list of mjkin.build.Link records, got {type(links).__name__}")
    if not links:
        raise InputError("links_mjcf needs at least one link")
    by_name: dict[str, tuple[Link, ET.Element, Array]] = {}
    extent = sum(abs(lk.length) for lk in links) or 1.0
    root, world = _document(name, extent)
    for i, lk in enumerate(links):
        if lk.name in by_name:
            raise InputError(f"link name {lk.name!r} is used twice")
        if lk.parent is not None and lk.parent not in by_name:
            known = ", ".join(repr(n) for n in by_name) or "none yet"
            raise InputError(f"link {lk.name!r}: parent {lk.parent!r} is not listed before it (links so far: {known})")
        if lk.parent is None:
            parent_el, at_default = world, np.zeros(3)
        else:
            _, parent_el, at_default = by_name[lk.parent]
        at = at_default if lk.at is None else check_vector(lk.at, f"link {lk.name!r} at")
        tip = _unit(lk.direction, f"link {lk.name!r} direction") * float(lk.length)
        body = ET.SubElement(parent_el, "body", name=lk.name, pos=_num(at))
        if lk.joint != "fixed":
            attrs = {"name": f"{lk.name}_joint", "type": lk.joint}
            if lk.joint != "ball":
                attrs["axis"] = _num(_unit(lk.axis, f"link {lk.name!r} axis"))
            if lk.range is not None:
                attrs["range"] = _num(check_vector(lk.range, f"link {lk.name!r} range", 2))
                attrs["limited"] = "true"
            ET.SubElement(body, "joint", attrs)
        radius = float(lk.radius) if lk.radius is not None else 0.04 * max(abs(lk.length), 0.25)
        geom = {"name": lk.name, "size": _num(radius), "rgba": _COLOURS[i % len(_COLOURS)]}
        if np.linalg.norm(tip) > 1e-9:
            ET.SubElement(body, "geom", geom, type="capsule", fromto=_num(np.concatenate([np.zeros(3), tip])))
        else:
            ET.SubElement(body, "geom", geom, type="sphere")
        ET.SubElement(body, "site", name=f"{lk.name}_tip", pos=_num(tip), size=_num(0.5 * radius))
        by_name[lk.name] = (lk, body, tip)
    last = ee if ee is not None else links[-1].name
    if last not in by_name:
        raise InputError(f"ee link {last!r} is not one of the links: {', '.join(by_name)}")
    _, body, tip = by_name[last]
    ET.SubElement(body, "site", name="ee", pos=_num(tip), size=_num(0.03 * extent), rgba="0.9 0.2 0.2 1")
    return _to_string(root)


def planar_chain(lengths: Sequence[float], ranges: Sequence[tuple[float, float] | None] | None = None,
                 name: str = "planar_chain") -> str:
    """MJCF of an n-link planar arm in the x–y plane: hinge ``j<i>`` about z, link ``link<i>`` along x."""
    sizes = check_array(lengths, "planar_chain lengths")
    if sizes.ndim != 1 or len(sizes) == 0:
        raise InputError(f"planar_chain needs at least one link length (a list of them), got shape {sizes.shape}")
    if ranges is not None and not isinstance(ranges, list | tuple):
        raise InputError(f"planar_chain ranges must be a list of (lo, hi) or None, got {type(ranges).__name__}")
    if ranges is not None and len(ranges) != len(sizes):
        raise InputError(f"planar_chain: {len(ranges)} ranges for {len(sizes)} links")
    links = [Link(name=f"link{i + 1}", parent=None if i == 0 else f"link{i}", length=float(L),
                  range=None if ranges is None else ranges[i]) for i, L in enumerate(sizes)]
    return links_mjcf(links, name=name)


def _dh_rows(rows: ArrayLike) -> Array:
    a = check_array(rows, "a DH table")
    if a.ndim != 2 or a.shape[1] != 4 or len(a) == 0 or not np.all(np.isfinite(a)):
        raise InputError(f"a DH table is an (n, 4) array of finite (a, alpha, d, theta) rows, got shape {a.shape}")
    return a


def _rot(axis: int, angle: float) -> Array:
    return spatial.axis_angle_to_mat(np.eye(3)[axis], np.asarray(angle))


def _dh_fixed(row: Array, convention: str) -> tuple[Array, Array]:
    """Rotation and translation of a DH row with the joint variable at its offset value."""
    a, alpha, d, theta = row
    Rz, Rx = _rot(2, theta), _rot(0, alpha)
    if convention == "standard":  # RotZ(theta) TransZ(d) TransX(a) RotX(alpha)
        return Rz @ Rx, np.array([0.0, 0.0, d]) + Rz @ np.array([a, 0.0, 0.0])
    # modified (Craig): RotX(alpha) TransX(a) RotZ(theta) TransZ(d)
    return Rx @ Rz, np.array([a, 0.0, 0.0]) + Rx @ np.array([0.0, 0.0, d])


def _check_dh(rows: Array, joints: str, convention: str) -> None:
    check_choice(convention, "DH convention", ("standard", "modified"))
    if not isinstance(joints, str) or len(joints) != len(rows) or set(joints) - {"R", "P"}:
        raise InputError(f"joints must be one letter R (revolute) or P (prismatic) per row, got {joints!r}")


def dh_chain(rows: ArrayLike, joints: str | None = None, convention: str = "standard",
             ranges: Sequence[tuple[float, float] | None] | None = None, name: str = "dh_chain") -> str:
    """MJCF of a serial chain from a DH table.

    Args:
        rows: ``(n, 4)`` rows ``(a, alpha, d, theta)``; for a revolute joint ``theta``
            is its offset, for a prismatic one ``d`` is.
        joints: ``"R"``/``"P"`` per row (default all revolute).
        convention: ``"standard"``: ``T_i = RotZ(θ) TransZ(d) TransX(a) RotX(α)``,
            joint i moves about z of frame i-1; ``"modified"`` (Craig):
            ``T_i = RotX(α) TransX(a) RotZ(θ) TransZ(d)``, joint i about z of frame i.
        ranges: optional ``(lo, hi)`` per joint (radians or metres).
        name: the MJCF model name.

    The site ``ee`` is frame n of the table, so ``pose(q, "ee") == dh_fk(rows, q)``.
    """
    table = _dh_rows(rows)
    kinds = "R" * len(table) if joints is None else joints
    _check_dh(table, kinds, convention)
    extent = float(np.sum(np.abs(table[:, [0, 2]]))) or 1.0
    root, parent = _document(name, extent)
    fixed = [_dh_fixed(row, convention) for row in table]
    ident = (np.eye(3), np.zeros(3))
    radius = 0.03 * extent
    frame = ident
    for i, kind in enumerate(kinds):
        if convention == "standard":  # body i is frame i-1; frame i sits at the row's fixed transform
            (R, p), frame = (fixed[i - 1] if i else ident), fixed[i]
            bone_end = frame[1]
        else:  # body i is frame i; the bone runs to the next frame's origin
            (R, p), frame = fixed[i], ident
            bone_end = fixed[i + 1][1] if i + 1 < len(fixed) else np.zeros(3)
        body = ET.SubElement(parent, "body", name=f"link{i + 1}", pos=_num(p), quat=_num(spatial.mat_to_quat(R)))
        joint = {"name": f"j{i + 1}", "type": "hinge" if kind == "R" else "slide", "axis": "0 0 1"}
        limits = None if ranges is None else ranges[i]
        if limits is not None:
            joint.update(range=_num(limits), limited="true")
        ET.SubElement(body, "joint", joint)
        geom = {"name": f"link{i + 1}", "size": _num(radius), "rgba": _COLOURS[i % len(_COLOURS)]}
        if np.linalg.norm(bone_end) > 1e-9:
            ET.SubElement(body, "geom", geom, type="capsule", fromto=_num(np.concatenate([np.zeros(3), bone_end])))
        else:
            ET.SubElement(body, "geom", geom, type="sphere")
        ET.SubElement(body, "site", name=f"link{i + 1}_tip", pos=_num(frame[1]),
                      quat=_num(spatial.mat_to_quat(frame[0])), size=_num(0.5 * radius))
        parent = body
    ET.SubElement(parent, "site", name="ee", pos=_num(frame[1]), quat=_num(spatial.mat_to_quat(frame[0])),
                  size=_num(0.05 * extent), rgba="0.9 0.2 0.2 1")
    return _to_string(root)


def dh_fk(rows: ArrayLike, q: ArrayLike, joints: str | None = None, convention: str = "standard") -> Array:
    """Pose ``(..., 4, 4)`` of frame n of a DH table for joint values ``q (..., n)`` (plain numpy)."""
    table = _dh_rows(rows)
    kinds = "R" * len(table) if joints is None else joints
    _check_dh(table, kinds, convention)
    q = check_array(q, "q")
    if q.ndim == 0 or q.shape[-1] != len(table):
        raise InputError(f"q must hold one value per DH row (..., {len(table)}), got shape {q.shape}")
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
    for i, (row, kind) in enumerate(zip(table, kinds, strict=True)):
        a, alpha, d, theta = row
        var = q[..., i]
        th = theta + var if kind == "R" else theta + 0 * var
        dd = d + var if kind == "P" else d + 0 * var
        Rz = spatial.axis_angle_to_mat(np.array([0.0, 0.0, 1.0]), th)
        Rx = _rot(0, alpha)
        if convention == "standard":
            step = spatial.make_transform(Rz @ Rx, np.stack([a * np.cos(th), a * np.sin(th), dd], -1))
        else:
            pz = Rx @ np.array([0.0, 0.0, 1.0])
            step = spatial.make_transform(Rx @ Rz, np.array([a, 0.0, 0.0]) + dd[..., None] * pz)
        T = T @ step
    return T
