"""The kinematic tree read from a compiled MuJoCo model, and :func:`load`."""

from __future__ import annotations

import hashlib
import math
import os
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Literal

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import spatial
from ..errors import InputError, MjkinIOError, ModelError, UnknownNameError
from ..runtime import files, tier
from ..runtime.checks import check_array, check_vector
from . import chain as chains
from . import qspace
from .assets import check_named_files
from .chain import ancestors, chain_of, chain_pose, pose_of, poses_of
from .com import com_many
from .distance import distances
from .fk import Kinematics, Plan, kinematic_arrays, moved
from .frames import Frames, forward, poses
from .geoms import Geoms, geom_arrays
from .jacobian import frame_jacobian_one

Array = NDArray[np.float64]
Kind = Literal["body", "joint", "site"]


def _ro(a: ArrayLike, dtype: type = np.float64) -> NDArray:
    out: NDArray = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Tree:
    """An articulated tree: bodies (links) joined by hinge, slide, ball and free joints.

    Everything is read once from a compiled :class:`mujoco.MjModel` into
    read-only arrays; mjkin's FK and Jacobians use only these. Body 0 is the
    world. Ids equal MuJoCo's, so results index like ``MjData.xpos``.

    Two fields are caches, neither pickled: ``chains`` maps a frame ``(name, kind)`` given to
    :meth:`pose` to the chain of its body's ancestors (:mod:`mjkin.kinematics.chain`),
    made by :meth:`pose` the first time the frame is asked for; only :meth:`pose`
    writes it. ``problems`` holds the :class:`~mjkin.Problem` objects :func:`mjkin.solve`
    made on this tree, by structure (:mod:`mjkin.ik.solve` alone reads and writes it): kept on
    the tree, they go with it. Everything else is fixed at construction
    (the chains, like ``bodies_chain``, are left writable only for numba's sake).
    """

    model: mujoco.MjModel
    body_parent: NDArray[np.int64]  # (nbody,)
    body_pos: Array  # (nbody, 3) in the parent frame
    body_rot: Array  # (nbody, 3, 3) in the parent frame
    jnt_type: NDArray[np.int64]  # (njnt,)
    jnt_body: NDArray[np.int64]
    jnt_qadr: NDArray[np.int64]
    jnt_dofadr: NDArray[np.int64]
    jnt_pos: Array  # (njnt, 3) anchor in the body frame
    jnt_axis: Array  # (njnt, 3) unit axis in the body frame
    jnt_limited: NDArray[np.bool_]
    jnt_range: Array  # (njnt, 2); for ball joints (0, max angle)
    qpos0: Array  # (nq,)
    site_body: NDArray[np.int64]
    site_pos: Array
    site_rot: Array
    # derived once at construction, never written afterwards
    layout: qspace.Layout = field(init=False, repr=False)  # joints grouped by kind, for vectorised q arithmetic
    plan: Plan = field(init=False, repr=False)  # index arrays that drive the vectorised FK
    body_dofs: tuple[NDArray[np.int64], ...] = field(init=False, repr=False)  # dofs moving each body, ascending
    kin: Kinematics = field(init=False, repr=False)  # what the compiled kernels read
    bodies_chain: Array = field(init=False, repr=False)  # every body as one chain: the one-q path of fk
    chains: dict[tuple[str, str | None], Array] = field(init=False, repr=False)  # the one-q path of pose, see below
    problems: dict = field(init=False, repr=False)  # mjkin.solve's problems by structure (mjkin.ik.solve)
    geoms: Geoms = field(init=False, repr=False)  # the geoms, for the compiled distances
    fk_args: tuple = field(init=False, repr=False)  # fk_kernel's arrays after q, in its order
    n_inner: int = field(init=False, repr=False)  # joints that are not their body's last
    ids: dict[str, dict[str, int]] = field(init=False, repr=False)  # name -> id, per element kind
    frames: dict[tuple[str, int], tuple[int, Array]] = field(init=False, repr=False)  # (kind, id) -> body, pose

    def __post_init__(self) -> None:
        def put(name: str, value: object) -> None:
            object.__setattr__(self, name, value)

        put("ids", {k: {n: i for i, n in enumerate(self._names(k)) if n} for k in ("body", "joint", "site")})
        put("layout", qspace.Layout.of(self))
        put("plan", Plan.of(self))
        m = self.model
        own = [list(range(m.body_dofadr[b], m.body_dofadr[b] + m.body_dofnum[b])) if m.body_dofnum[b] else []
               for b in range(m.nbody)]
        dofs: list[list[int]] = [[] for _ in range(m.nbody)]
        for b in range(1, m.nbody):
            dofs[b] = sorted(dofs[int(self.body_parent[b])] + own[b])
        put("body_dofs", tuple(_ro(d, np.int64) for d in dofs))
        k = kinematic_arrays(self)
        put("kin", k)
        put("bodies_chain", chain_of(self, list(range(m.nbody)), np.eye(4)))
        put("chains", {})
        put("problems", {})
        put("geoms", geom_arrays(m))
        put("fk_args", (k.parent, k.fixed_rot, k.fixed_pos, k.jnt_start, k.jnt_count, k.jnt_inner, k.fixed_plain,
                        k.hinge_coord, k.anchor_zero, k.jnt_type, k.jnt_qadr, k.jnt_axis, k.jnt_pos, k.qpos0))
        put("n_inner", int(np.count_nonzero(k.jnt_inner >= 0)))
        frames: dict[tuple[str, int], tuple[int, Array]] = {("body", b): (b, _ro(np.eye(4))) for b in range(m.nbody)}
        for i in range(m.nsite):
            T = spatial.make_transform(self.site_rot[i], self.site_pos[i])
            frames["site", i] = (int(self.site_body[i]), _ro(T))
        put("frames", frames)

    def __getstate__(self) -> dict:
        """Pickle the tree without its caches :attr:`chains` and :attr:`problems` (they arrive empty)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("chains", "problems")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, chains={}, problems={})

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> Tree:
        """Read the kinematic tree of a compiled model.

        Raises:
            ModelError: a number the tree reads is NaN or inf (MuJoCo compiles them with a warning only).
        """
        check_finite(model)
        _warn_reversed_ranges(model)
        return cls(
            model=model,
            body_parent=_ro(model.body_parentid, np.int64),
            body_pos=_ro(model.body_pos),
            body_rot=_ro(spatial.quat_to_mat(spatial.quat_normalize(model.body_quat))),
            jnt_type=_ro(model.jnt_type, np.int64),
            jnt_body=_ro(model.jnt_bodyid, np.int64),
            jnt_qadr=_ro(model.jnt_qposadr, np.int64),
            jnt_dofadr=_ro(model.jnt_dofadr, np.int64),
            jnt_pos=_ro(model.jnt_pos),
            jnt_axis=_ro(model.jnt_axis),
            jnt_limited=_ro(model.jnt_limited, bool),
            jnt_range=_ro(model.jnt_range),
            qpos0=_ro(model.qpos0),
            site_body=_ro(model.site_bodyid, np.int64),
            site_pos=_ro(model.site_pos),
            site_rot=_ro(spatial.quat_to_mat(spatial.quat_normalize(model.site_quat))),
        )

    # ------------------------------------------------------------- sizes, names
    @property
    def name(self) -> str:
        """The model's name (MJCF ``<mujoco model=...>``)."""
        return bytes(self.model.names).split(b"\0", 1)[0].decode()

    # the sizes are read once: a solve reads them several times, and MjModel's attributes cost ~0.2 µs each
    @cached_property
    def nq(self) -> int:
        """Length of a configuration q (MuJoCo's ``nq``)."""
        return int(self.model.nq)

    @cached_property
    def nv(self) -> int:
        """Degrees of freedom, the number of Jacobian columns (MuJoCo's ``nv``)."""
        return int(self.model.nv)

    @cached_property
    def nbody(self) -> int:
        """Number of bodies, the world (id 0) included."""
        return int(self.model.nbody)

    @cached_property
    def njnt(self) -> int:
        """Number of joints."""
        return int(self.model.njnt)

    def names(self, kind: Kind) -> list[str]:
        """Names of all bodies, joints or sites in id order (unnamed ones as ``""``)."""
        return list(self._names(kind))

    def _names(self, kind: str) -> tuple[str, ...]:
        count = {"body": self.model.nbody, "joint": self.model.njnt, "site": self.model.nsite}
        if not isinstance(kind, str) or kind not in count:
            raise InputError(f"kind must be 'body', 'joint' or 'site', not {kind!r}")
        return tuple(self.model.names[self._name_adr(kind)[i]:].split(b"\0", 1)[0].decode()
                     for i in range(count[kind]))

    def _name_adr(self, kind: str) -> NDArray:
        m = self.model
        return {"body": m.name_bodyadr, "joint": m.name_jntadr, "site": m.name_siteadr}[kind]

    def id(self, name: str, kind: Kind) -> int:
        """MuJoCo id of a named body, joint or site; :class:`UnknownNameError` lists the names."""
        if not isinstance(kind, str) or kind not in self.ids:
            raise InputError(f"kind must be 'body', 'joint' or 'site', not {kind!r}")
        ids = self.ids[kind]
        if not isinstance(name, str) or name not in ids:
            raise UnknownNameError(kind, name, list(ids))
        return ids[name]

    def frame(self, name: str, kind: Kind | None = None) -> tuple[Literal["body", "site"], int]:
        """Resolve a frame name to ``(kind, id)``; ``kind=None`` tries sites first, then bodies."""
        if kind is not None and not (isinstance(kind, str) and kind in ("site", "body")):  # an array: no ==
            raise InputError(f"frame kind must be 'site', 'body' or None, not {kind!r}")
        if kind is None:
            for k in ("site", "body"):
                if isinstance(name, str) and name in self.ids[k]:
                    return k, self.ids[k][name]  # type: ignore[return-value]
            raise UnknownNameError("site or body", name, {"sites": self.ids["site"], "bodies": self.ids["body"]})
        return kind, self.id(name, kind)

    def frame_body(self, name: str, kind: Kind | None = None) -> tuple[int, Array]:
        """The body a frame is fixed to and the frame's pose in that body ``(4, 4)`` (read-only)."""
        return self.frames[self.frame(name, kind)]

    def check_near(self, pos: ArrayLike, what: str) -> None:
        """Refuse a target point ``pos (3,)`` (world, m) farther than :data:`FAR` model extents from the model.

        No figure reaches it, and at ~1e154 m its squared distance overflows. ``what`` names it in the error.

        Raises:
            InputError: the point is that far, or not finite.
        """
        p = np.asarray(pos, dtype=float)
        reach = FAR * (float(self.model.stat.extent) or 1.0)
        if not math.hypot(*(p - self.model.stat.center)) <= reach:  # hypot: no overflow on the way
            at = ", ".join(f"{x:.3g}" for x in p)
            raise InputError(f"{what} would be at [{at}], more than {FAR:g} model extents ({reach:.3g} m) from the "
                             "model; keep targets within that")

    # ------------------------------------------------------------------ joints
    def check_q(self, q: ArrayLike, name: str = "q") -> Array:
        """``q`` as float64 ``(..., nq)``; raises :class:`InputError` for a wrong shape or NaN/inf."""
        return qspace.check(self, q, name)

    def random_q(self, rng: np.random.Generator | int | None = None, n: int | tuple[int, ...] | None = None) -> Array:
        """Random configurations inside the joint limits: ``(n, nq)``, ``n + (nq,)`` for a shape, ``(nq,)`` for None."""
        return qspace.random(self, rng, n)

    def clip(self, q: ArrayLike) -> Array:
        """Project ``q (..., nq)`` into the joint limits and renormalise quaternions."""
        return qspace.clip(self, self.check_q(q))

    def integrate(self, q: ArrayLike, v: ArrayLike) -> Array:
        """Move ``q (..., nq)`` along a velocity ``v (..., nv)`` for unit time (as ``mj_integratePos``)."""
        return qspace.integrate(self, self.check_q(q), check_array(v, "v"))

    def difference(self, q1: ArrayLike, q0: ArrayLike, periodic: bool = False) -> Array:
        """Velocity ``(..., nv)`` that takes ``q0`` to ``q1`` in unit time (as ``mj_differentiatePos``).

        ``periodic=True``: unlimited hinges the short way round (``(-π, π]``), for steps between poses
        whose hinge angles were wrapped (as :func:`mjkin.solve` returns them).
        """
        return qspace.difference(self, self.check_q(q1, "q1"), self.check_q(q0, "q0"), periodic)

    # -------------------------------------------------------------- kinematics
    @tier.first_use
    def kinematics(self, q: ArrayLike) -> Frames:
        """All body frames (and, on demand, dof axes) for ``q (..., nq)``."""
        return forward(self, self.check_q(q))

    def fk(self, q: ArrayLike) -> Array:
        """World pose of every body, ``(..., nbody, 4, 4)``; index = MuJoCo body id, 0 = world."""
        T = poses_of(self.bodies_chain, q)  # one compiled call for a plain 1-D q, which checks it too
        if T is None:  # a few rows: the same call for each
            T = chains.rows_of(poses_of, self.bodies_chain, q)
        if T is None and not chains.is_ready():  # a one-q pose before the compiled call
            q = self.check_q(q)
            T = np.empty((self.model.nbody, 4, 4))
            if q.ndim == 1 and chains.one_pose(chains.chain_poses, self.bodies_chain,
                                               np.require(q, requirements=["C", "W"]), T):
                return T
            T = None
        return poses(self, self.check_q(q)) if T is None else T

    def pose(self, q: ArrayLike, name: str, kind: Kind | None = None) -> Array:
        """World pose ``(..., 4, 4)`` of a site or body (``kind=None``: a site of that name first)."""
        try:
            chain = self.chains.get((name, kind))  # a frame seen before
        except TypeError:  # an unhashable name or kind is no frame: the checked path below says so
            chain = None
        if chain is not None:  # one compiled call for a plain 1-D q (or one per row of a few), which checks it too
            if (T := pose_of(chain, q)) is not None or (T := chains.rows_of(pose_of, chain, q)) is not None:
                return T  # (else the path below says why)
        q = self.check_q(q)
        if q.ndim == 1:  # the one-q entry, compiled (or loaded) on the first one-q pose, or meanwhile interpreted
            T = np.empty((4, 4))
            if chains.one_pose(chain_pose, self._chain(name, kind), np.require(q, requirements=["C", "W"]), T):
                return T
        elif (T := chains.rows_of(pose_of, self._chain(name, kind), q)) is not None:  # a few rows: the same call each
            return T
        return self.kinematics(q).pose(*self.frame(name, kind))  # a batch (or a chain too long for chain_pose)

    def _chain(self, name: str, kind: Kind | None) -> Array:
        """The chain of a frame (:mod:`mjkin.kinematics.chain`), from :attr:`chains` (made there once)."""
        body, local = self.frame_body(name, kind)  # raises for what names no frame
        if (name, kind) not in self.chains:
            self.chains[name, kind] = chain_of(self, ancestors(self, body), local)
        return self.chains[name, kind]

    @tier.first_use
    def jacobian(self, q: ArrayLike, name: str, kind: Kind | None = None,
                 offset: ArrayLike | None = None) -> Array:
        """Jacobian ``(..., 6, nv)`` at a site/body origin, or at ``offset (3,)`` in its local frame.

        Rows are ``[linear; angular]`` in world-aligned axes, as ``mj_jac`` stacked
        ``[jacp; jacr]``: ``d(point, world)/dt = J[:3] @ qvel`` and ``omega = J[3:] @ qvel``.
        """
        q = self.check_q(q)
        if q.ndim > 1:
            return self.kinematics(q).jacobian(*self.frame(name, kind), offset=offset)
        body, local = self.frame_body(name, kind)  # local: read-only, and so is a moved one: one compiled version
        if offset is not None:
            local = moved(local, check_vector(offset, "offset"))
            local.setflags(write=False)
        J = np.empty((6, self.nv))
        frame_jacobian_one(self.kin, np.require(q, requirements=["C", "W"]).reshape(1, -1), body, local, J)
        return J

    def com(self, q: ArrayLike) -> Array:
        """Whole-figure centre of mass ``(..., 3)`` (world, m) at ``q (..., nq)``; MuJoCo's ``subtree_com[0]``."""
        return self._com(q)[0]

    def com_jacobian(self, q: ArrayLike) -> Array:
        """Jacobian ``(..., 3, nv)`` of :meth:`com`: its velocity is ``J @ v``; MuJoCo's ``mj_jacSubtreeCom(.., 0)``."""
        return self._com(q)[1]

    def distances(self, q: ArrayLike, pairs: ArrayLike | None = None) -> Array:
        """Signed distances ``(..., P)`` (m, < 0 = penetration) of geom pairs ``(P, 2)`` at ``q (..., nq)``.

        Default pairs: those MuJoCo's collision tests (:func:`mjkin.kinematics.geoms.contact_pairs`);
        see :mod:`mjkin.kinematics.distance`.
        """
        return distances(self, q, pairs)

    def _com(self, q: ArrayLike) -> tuple[Array, Array]:
        f = self.kinematics(q)
        B = f.rot.shape[0]
        C, J = np.empty((B, 3)), np.empty((B, 3, self.nv))
        com_many(self.kin, f.rot, f.pos, f.inner_rot, f.inner_pos, C, J)
        return C.reshape(f.batch + (3,)), J.reshape(f.batch + (3, self.nv))


# what Tree (and, for contacts, Scene) reads from a model: (element kind, MjModel array, what it is)
_FINITE = (("body", "body_pos", "pos"), ("body", "body_quat", "quat"), ("joint", "jnt_pos", "pos"),
           ("joint", "jnt_axis", "axis"), ("joint", "jnt_range", "range"), ("site", "site_pos", "pos"),
           ("site", "site_quat", "quat"), ("geom", "geom_pos", "pos"), ("geom", "geom_quat", "quat"),
           ("geom", "geom_size", "size"))
class ReversedRangeWarning(UserWarning):
    """A hinge or slide's ``range`` has its lower bound above its upper one, so MuJoCo left it unlimited."""


def _warn_reversed_ranges(model: mujoco.MjModel) -> None:
    """Warn, once per model, about joints written ``range="1 -1"``: MuJoCo compiles them unlimited, silently."""
    lo, hi = model.jnt_range[:, 0], model.jnt_range[:, 1]
    ranged = model.jnt_type >= int(mujoco.mjtJoint.mjJNT_SLIDE)  # slides and hinges
    bad = np.flatnonzero(~model.jnt_limited.astype(bool) & (lo > hi) & ranged)
    if len(bad):
        named = ", ".join(f"{model.joint(int(j)).name or int(j)!r} ({lo[j]:g} {hi[j]:g})" for j in bad[:8])
        warnings.warn(f"joint range with its lower bound above the upper one, which MuJoCo compiles as unlimited: "
                      f"{named}{' ...' if len(bad) > 8 else ''}; write it lower first (range=\"-1 1\")",
                      ReversedRangeWarning, stacklevel=3)


FAR = 1000.0  # model extents (MjModel.stat.extent) from the model's centre past which a target point is refused
_NAME_ADR = {"body": "name_bodyadr", "joint": "name_jntadr", "site": "name_siteadr", "geom": "name_geomadr"}


def check_finite(model: mujoco.MjModel) -> None:
    """Refuse a model with a NaN or inf where the kinematics (or contacts) read it; the message names the element.

    Raises:
        ModelError: e.g. ``joint 'j1' has a non-finite axis [nan 0. 1.]``.
    """
    qpos0 = np.asarray(model.qpos0)  # a joint's ref; a free body's pos and quat are checked with the bodies
    ref = np.searchsorted(model.jnt_qposadr, np.flatnonzero(~np.isfinite(qpos0)), side="right") - 1
    for kind, attr, what in _FINITE + (("joint", None, "reference position (qpos0)"),):
        bad = np.flatnonzero(~np.isfinite(getattr(model, attr)).all(axis=-1)) if attr else ref
        if len(bad):
            i = int(bad[0])
            name = model.names[getattr(model, _NAME_ADR[kind])[i]:].split(b"\0", 1)[0].decode()
            value = f" {getattr(model, attr)[i]}" if attr else ""
            raise ModelError(f"{kind} {repr(name) if name else i} has a non-finite {what}{value}; "
                             "every number of a body, joint, site and geom must be finite")


def check_tree(tree: object) -> Tree:
    """``tree`` if it is a :class:`Tree`, else :class:`InputError` saying what was given (an entry's first check)."""
    if not isinstance(tree, Tree):
        raise InputError(f"tree must be a mjkin.Tree (mjkin.load(name or path)), got {type(tree).__name__}")
    return tree


def fingerprint(tree: Tree) -> str:
    """A short hash of the kinematic structure (bodies, joints, limits, sites): same model, same print."""
    h = hashlib.sha256()
    for a in (tree.body_parent, tree.body_pos, tree.body_rot, tree.jnt_type, tree.jnt_body, tree.jnt_pos,
              tree.jnt_axis, tree.jnt_range, tree.qpos0, tree.site_body, tree.site_pos):
        h.update(np.ascontiguousarray(np.round(a, 12)).tobytes())
    return h.hexdigest()[:16]


def bundled_models() -> dict[str, Path]:
    """Models shipped with mjkin, by name (file stem)."""
    from importlib.resources import files

    root = Path(str(files("mjkin.models")))
    return {p.stem: p for p in sorted(root.glob("*.xml"))}


def source_of(model: str) -> str:
    """Where the model argument ``model`` loads from, as a script records it: a file's absolute path, else as given."""
    path = Path(model)
    return str(path.resolve()) if path.is_file() else model


def load(src: str | os.PathLike[str] | mujoco.MjModel | mujoco.MjSpec) -> Tree:
    """Read a kinematic tree.

    ``src`` is an MJCF or URDF path, an XML string, the name of a bundled model,
    a :class:`mujoco.MjSpec` or a compiled :class:`mujoco.MjModel`.

    Raises:
        MjkinIOError: the file does not exist or cannot be read.
        ModelError: MuJoCo cannot compile it (the message says why).
    """
    if isinstance(src, mujoco.MjModel):
        return Tree.from_model(src)
    try:
        if isinstance(src, mujoco.MjSpec):
            return Tree.from_model(src.compile())
        text = os.fspath(src)
        if text.lstrip().startswith("<"):
            return Tree.from_model(mujoco.MjModel.from_xml_string(text))
        path = Path(text)
        if not path.exists() and path.suffix == "" and text in bundled_models():
            path = bundled_models()[text]
        if os.path.isdir(path):
            found = sorted(p.name for p in path.glob("*.xml"))[:8]
            raise MjkinIOError(f"{text!r} is a folder, not a model file: give the MJCF/URDF file in it"
                               + (f" ({', '.join(found)})" if found else ""))
        if not os.path.lexists(path):
            hint = ", ".join(bundled_models())
            raise MjkinIOError(f"model file not found: {text!r} (give an MJCF/URDF path or one of: {hint})")
        files.check_input(path, "model file", files.LIMITS["model"], hint="give the MJCF/URDF file itself")
        check_named_files(path)
        return Tree.from_model(mujoco.MjModel.from_xml_path(str(path)))
    except (ValueError, mujoco.FatalError) as e:
        msg = " ".join(str(e).split())
        raise ModelError(f"cannot compile model {_describe(src)}: {msg}") from None
    except TypeError as e:
        raise InputError(f"load() takes a path, XML string, MjSpec or MjModel, not {type(src).__name__}") from e


def _describe(src: object) -> str:
    text = str(src) if not isinstance(src, mujoco.MjSpec) else "<MjSpec>"
    return repr(text if len(text) < 80 and "\n" not in text else text.lstrip()[:40] + "...")
