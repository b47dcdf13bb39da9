"""The chains other libraries are given in ``mjkin bench``: the same arm, written in their terms, checked equal.

Robotics Toolbox gets a ``DHRobot`` of ``RevoluteMDH`` links whose modified-DH table is
read back from the model itself (its bodies' fixed transforms) and the frame as its tool;
TRAC-IK (``pytracik``) and pinocchio get a URDF written from the model's chain. Before
any timing each peer's forward kinematics is compared with ``tree.pose`` on random
in-limit configurations: a peer that differs by more than :data:`CHAIN_TOL` gets no row,
only the reason (:class:`Unavailable`).
"""

from __future__ import annotations

import importlib
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any, Literal

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...kinematics.qspace import HINGE
from ...kinematics.tree import Tree
from ...runtime.files import write_text
from ...spatial import make_transform, quat_to_euler, quat_to_mat

Array = NDArray[np.float64]
Kind = Literal["site", "body"]
CHAIN_TOL = 1e-12  # largest difference of a peer's frame pose (metres, rotation-matrix entries) from tree.pose
ROOT_LINK = "chain_root"  # the URDF's fixed root link: the world
INSTALL = "pip install 'mjkin[bench]'"


class Unavailable(Exception):
    """Why a peer gets no row: not installed, a chain it cannot take, or an FK that differs from mjkin's."""


def require(module: str, package: str) -> ModuleType:
    """Import a peer's module, or raise :class:`Unavailable` naming the package to install."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise Unavailable(f"{package} is not installed ({INSTALL}): {e}") from None


@dataclass(frozen=True)
class Chain:
    """The serial chain from the world to a frame, holding every joint of the model.

    ``bodies`` run root first (world excluded); ``joint[i]`` is the hinge of ``bodies[i]``
    or -1 for a body welded to its parent. ``tip`` is the frame's pose in the last body
    (identity for a body frame); ``tip_name`` names it (the site, or the last body).
    """

    bodies: tuple[int, ...]
    joint: tuple[int, ...]
    tip: Array
    tip_name: str


def serial_chain(tree: Tree, frame: str, kind: Kind) -> Chain:
    """The chain to ``frame``; raises :class:`Unavailable` unless it is a serial chain of hinges.

    Every joint of the model must lie on the chain, be a hinge placed at its body's origin
    with ``qpos0 = 0``, one per body: what a URDF joint or a DH row can say.
    """
    m = tree.model
    if not m.njnt:
        raise Unavailable("the model has no joint")
    obj = mujoco.mjtObj.mjOBJ_SITE if kind == "site" else mujoco.mjtObj.mjOBJ_BODY
    i = mujoco.mj_name2id(m, obj, frame)
    body = int(m.site_bodyid[i]) if kind == "site" else i
    tip = make_transform(quat_to_mat(m.site_quat[i]), m.site_pos[i]) if kind == "site" else np.eye(4)
    bodies = []
    while body > 0:
        bodies.append(body)
        body = int(m.body_parentid[body])
    bodies.reverse()
    joints = []
    for b in bodies:
        if m.body_jntnum[b] > 1:
            raise Unavailable(f"body {m.body(b).name!r} has {m.body_jntnum[b]} joints; a URDF link has one")
        j = int(m.body_jntadr[b]) if m.body_jntnum[b] else -1
        if j >= 0 and (m.jnt_type[j] != HINGE or np.any(m.jnt_pos[j] != 0) or m.qpos0[m.jnt_qposadr[j]] != 0):
            raise Unavailable(f"joint {m.joint(j).name!r} is not a hinge at its body's origin with qpos0 = 0")
        joints.append(j)
    if [j for j in joints if j >= 0] != list(range(m.njnt)):
        raise Unavailable(f"not a serial chain: the model has {m.njnt} joints, {sum(j >= 0 for j in joints)} of them "
                          f"on the way to {frame!r}")
    return Chain(tuple(bodies), tuple(joints), tip, frame)


def _num(x: ArrayLike) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(x))


def _link_name(m: mujoco.MjModel, b: int) -> str:
    return m.body(b).name or f"body{b}"


def chain_urdf(tree: Tree, frame: str, kind: Kind) -> str:
    """A URDF of the chain to ``frame``: root link :data:`ROOT_LINK`, tip link named ``frame``.

    One link per chain body (its MuJoCo inertia, so MuJoCo itself can load the file), a
    revolute joint (continuous when unlimited) or a fixed one per body, with the body's
    fixed transform as the joint origin (full float precision), and for a site a last fixed
    joint to a link named after it. A ``<mujoco>`` element keeps MuJoCo from fusing the
    fixed links away; URDF readers that do not know it ignore it.
    """
    m = tree.model
    chain = serial_chain(tree, frame, kind)
    robot = ET.Element("robot", name=f"chain_to_{frame}")
    ET.SubElement(ET.SubElement(robot, "mujoco"), "compiler", fusestatic="false", discardvisual="false")
    ET.SubElement(robot, "link", name=ROOT_LINK)
    parent = ROOT_LINK
    for b, j in zip(chain.bodies, chain.joint, strict=True):
        name = _link_name(m, b)
        link = ET.SubElement(robot, "link", name=name)
        if m.body_mass[b] > 0:
            inertial = ET.SubElement(link, "inertial")
            _origin(inertial, m.body_ipos[b], m.body_iquat[b])
            ET.SubElement(inertial, "mass", value=_num(m.body_mass[b]))
            ixx, iyy, izz = m.body_inertia[b]
            ET.SubElement(inertial, "inertia", ixx=_num(ixx), iyy=_num(iyy), izz=_num(izz), ixy="0", ixz="0", iyz="0")
        kind_ = "fixed" if j < 0 else "revolute" if m.jnt_limited[j] else "continuous"
        joint_name = (m.joint(j).name or f"joint{j}") if j >= 0 else f"{name}_weld"
        joint = _joint(robot, joint_name, kind_, parent, name)
        _origin(joint, m.body_pos[b], m.body_quat[b])
        if j >= 0:
            ET.SubElement(joint, "axis", xyz=_num(m.jnt_axis[j]))
        if kind_ == "revolute":
            ET.SubElement(joint, "limit", lower=_num(m.jnt_range[j, 0]), upper=_num(m.jnt_range[j, 1]), effort="0",
                          velocity="0")
        parent = name
    if kind == "site":
        if frame in {_link_name(m, b) for b in chain.bodies}:
            raise Unavailable(f"site {frame!r} has the name of a body of its chain; a URDF link name is unique")
        ET.SubElement(robot, "link", name=frame)
        site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, frame)
        _origin(_joint(robot, f"{frame}_weld", "fixed", parent, frame), m.site_pos[site], m.site_quat[site])
    ET.indent(robot)
    return ET.tostring(robot, encoding="unicode") + "\n"


def _joint(robot: ET.Element, name: str, kind: str, parent: str, child: str) -> ET.Element:
    joint = ET.SubElement(robot, "joint", name=name, type=kind)
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    return joint


def _origin(parent: ET.Element, pos: ArrayLike, quat: ArrayLike) -> None:
    """``<origin xyz rpy>``: URDF's roll-pitch-yaw is the extrinsic x-y-z sequence."""
    ET.SubElement(parent, "origin", xyz=_num(pos), rpy=_num(quat_to_euler(quat, "xyz")))


def mdh_table(tree: Tree, frame: str, kind: Kind) -> tuple[Array, Array, Array]:
    """The chain as a modified-DH (Craig) table ``(n, 4)`` of rows ``(a, alpha, d, theta)``, base and tool ``(4, 4)``.

    Each hinged body's fixed transform is read as ``RotX(alpha) TransX(a) RotZ(theta) TransZ(d)``
    (hinge about its body's z); welded bodies before the first hinge make the base, those after
    the last one and the site the tool. Whether the table is the chain is for :func:`check_fk`
    to say: a transform of another form reads as a table whose FK differs.
    """
    m = tree.model
    chain = serial_chain(tree, frame, kind)
    hinged = [k for k, j in enumerate(chain.joint) if j >= 0]
    if hinged != list(range(hinged[0], hinged[-1] + 1)):
        raise Unavailable("a body without a joint between two hinges: a DH table has no row for it")
    rows = []
    for k in hinged:
        b, j = chain.bodies[k], chain.joint[k]
        if not np.allclose(m.jnt_axis[j], [0.0, 0.0, 1.0], rtol=0.0, atol=CHAIN_TOL):
            raise Unavailable(f"joint {m.joint(j).name!r} turns about {m.jnt_axis[j]}, not its body's z as DH "
                              "joints do")
        R, p = quat_to_mat(m.body_quat[b]), m.body_pos[b]
        alpha, theta = np.arctan2(-R[1, 2], R[2, 2]), np.arctan2(-R[0, 1], R[0, 0])
        rows.append((p[0], alpha, -np.sin(alpha) * p[1] + np.cos(alpha) * p[2], theta))
    base, tool = np.eye(4), np.eye(4)
    for k, b in enumerate(chain.bodies):
        if chain.joint[k] < 0:
            T = make_transform(quat_to_mat(m.body_quat[b]), m.body_pos[b])
            if k < hinged[0]:
                base = base @ T
            else:
                tool = tool @ T
    return np.array(rows), base, tool @ chain.tip


def check_fk(fk: Callable[[Array], Array], tree: Tree, frame: str, kind: Kind, who: str, n: int = 100,
             seed: int = 0) -> float:
    """Largest difference of ``fk(q) (4, 4)`` from ``tree.pose(q, frame)`` over ``n`` random in-limit q.

    Raises :class:`Unavailable` when it exceeds :data:`CHAIN_TOL` (then the peer gets no row).
    """
    Q = tree.random_q(np.random.default_rng(seed), n)
    mine = tree.pose(Q, frame, kind)
    err = max(float(np.abs(np.asarray(fk(q), dtype=float) - T).max()) for q, T in zip(Q, mine, strict=True))
    if not err <= CHAIN_TOL:
        raise Unavailable(f"{who}'s FK differs from tree.pose(q, {frame!r}) by {err:.1e} (> {CHAIN_TOL:g}) on random "
                          "in-limit configurations")
    return err


def rtb_ets(tree: Tree, frame: str, kind: Kind) -> Any:
    """Robotics Toolbox's robot of the chain, as the ``ETS`` its C++ ``ik_LM`` runs on, checked by its ``fkine``.

    A ``DHRobot`` of ``RevoluteMDH`` links with the table, base and tool of :func:`mdh_table`
    and the model's joint limits as ``qlim``.
    """
    rtb = require("roboticstoolbox", "roboticstoolbox-python")
    sm = require("spatialmath", "spatialmath-python")
    m = tree.model
    if not m.jnt_limited.all():
        raise Unavailable("a joint without limits: ik_LM draws its restarts within every joint's qlim")
    rows, base, tool = mdh_table(tree, frame, kind)
    links = [rtb.RevoluteMDH(a=a, alpha=alpha, d=d, offset=theta, qlim=m.jnt_range[j])
             for (a, alpha, d, theta), j in zip(rows, range(m.njnt), strict=True)]
    robot = rtb.DHRobot(links, name=f"chain_to_{frame}", base=sm.SE3(base, check=False),
                        tool=sm.SE3(tool, check=False))
    ets = robot.ets()
    check_fk(lambda q: ets.fkine(q).A, tree, frame, kind, "roboticstoolbox's DHRobot")
    return ets


def pinocchio_model(tree: Tree, frame: str, kind: Kind) -> tuple[Any, Any, int]:
    """Pinocchio's model, data and frame id of :func:`chain_urdf`, checked (``oMf`` after FK + frame placement)."""
    pin = require("pinocchio", "pin")
    model = pin.buildModelFromXML(chain_urdf(tree, frame, kind))
    if model.nq != tree.nq:
        raise Unavailable("pinocchio gives an unlimited (continuous) joint two coordinates, cos and sin; "
                          "only chains of limited hinges are compared")
    data, fid = model.createData(), model.getFrameId(frame)

    def fk(q: Array) -> Array:
        pin.forwardKinematics(model, data, q)
        return np.asarray(pin.updateFramePlacement(model, data, fid).homogeneous)

    check_fk(fk, tree, frame, kind, "pinocchio's model of the URDF")
    return model, data, fid


def trac_ik_solver(tree: Tree, frame: str, kind: Kind, timeout: float, eps: float) -> Any:
    """TRAC-IK through pytracik: its ``TracIK`` (Speed mode) on :func:`chain_urdf`, checked by its ``fk``.

    The URDF goes through a temporary file (``TracIK`` reads a path); ``timeout`` (s) and
    ``eps`` are TRAC-IK's own.
    """
    trac_ik = require("trac_ik", "pytracik")
    with tempfile.TemporaryDirectory() as folder:
        path = write_text(Path(folder) / "chain.urdf", chain_urdf(tree, frame, kind))
        solver = trac_ik.TracIK(ROOT_LINK, frame, str(path), timeout=timeout, epsilon=eps, solver_type="Speed")

    def fk(q: Array) -> Array:
        pos, rot = solver.fk(np.ascontiguousarray(q))
        return make_transform(rot, pos)

    check_fk(fk, tree, frame, kind, "TRAC-IK's chain of the URDF")
    return solver
