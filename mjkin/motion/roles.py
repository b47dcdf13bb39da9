"""Retargeting roles: which clip joint and which figure body stand for the pelvis, hips, knees, hands, head.

A clip's joints are matched by name (:data:`SOURCE_NAMES`). A figure's bodies are read from its kinematic tree
in the zero pose (``qpos0``: a humanoid standing, facing its root's +x with its left on +y, as MJCF humanoids
do), names telling only sides, heads and toes (:func:`find_figure`), so Menagerie-style robots map without a
table. A mapping file (:func:`read_mapping`) gives or overrides any role.
"""

from __future__ import annotations

import json
import os
import re
import weakref
from dataclasses import dataclass, replace
from functools import cached_property

import mujoco
import numpy as np
from numpy.typing import NDArray

from .. import spatial
from ..errors import InputError, MjkinIOError
from ..kinematics.tree import Tree
from ..runtime import files
from . import bvh

Array = NDArray[np.float64]
SIDES = ("left", "right")
LIMB = ("hip", "knee", "ankle", "shoulder", "elbow", "wrist")
REQUIRED = ("pelvis", "head", *(f"{s}_{p}" for s in SIDES for p in LIMB))
ROLES = (*REQUIRED, "left_toe", "right_toe", "neck")  # a clip's
FIGURE_ROLES = (*REQUIRED, "torso")  # a figure's

# Source joint names per role, by preference, compared lower-case without a namespace ('mixamorig:') or '_ -.';
# {s} is 'left'/'right', {c} 'l'/'r'. Mixamo's (and LAFAN1's, AMASS's) LeftShoulder is the collarbone, the
# 19-joint rig's the upper arm: LeftArm comes first, so each rig gets its own.
SOURCE_NAMES: dict[str, tuple[str, ...]] = {
    "pelvis": ("hips", "pelvis", "hip", "root"),
    "head": ("head",),
    "neck": ("neck", "neck1"),
    "hip": ("{s}upleg", "{s}hip", "{s}thigh", "{s}upperleg", "{c}thigh", "{c}hip", "{c}upleg"),
    "knee": ("{s}leg", "{s}knee", "{s}shin", "{s}lowerleg", "{c}shin", "{c}knee", "{c}leg"),
    "ankle": ("{s}foot", "{s}ankle", "{c}foot", "{c}ankle"),
    "toe": ("{s}toebase", "{s}toe", "{s}toes", "{c}toe", "{c}toes", "{s}footend", "{s}ankleend", "{c}footend"),
    "shoulder": ("{s}arm", "{s}upperarm", "{c}shldr", "{c}upperarm", "{c}humerus", "{s}shoulder", "{c}shoulder"),
    "elbow": ("{s}forearm", "{s}elbow", "{s}lowerarm", "{c}forearm", "{c}elbow", "{c}radius"),
    "wrist": ("{s}hand", "{s}wrist", "{c}hand", "{c}wrist"),
}

# Figure bodies: name tokens ('Hip_Pitch_Left' -> hip, pitch, left; 'l_hip_ie_link' -> l, hip, ie, link) tell
# sides, heads and toes; everything else comes from the tree and its geometry at qpos0.
LEFT, RIGHT = frozenset({"left", "l"}), frozenset({"right", "r"})
HEADS = frozenset({"head", "neck", "skull"})
TOES = frozenset({"toe", "toes"})
SOLE_BAND = 0.02  # a body whose geoms come within this share of the figure's height of its lowest point has a sole
LATERAL = 0.03  # a body this share of the height off the root's x-z plane is on that side, when names do not say
CENTRE_SPREAD = 0.03  # a joint axis passing this share of the height from the others' centre is not in the joint
# a figure without a head body: its head point this many shoulder spans above their midpoint (a person's head centre
# is 0.12 of the height above the shoulder joints, which are 0.22-0.26 of it apart), ...
HEAD_ABOVE = 0.5
HEAD_REACH = 0.25  # ... unless a torso geom centred above the shoulders reaches this many spans above them
WAIST_LEAN = 0.5  # the share of the source's lean (pelvis to shoulders) the pelvis takes when the torso can pitch
PITCH_RANGE = 0.3  # rad: a joint between pelvis and torso that turns this far about the figure's y pitches it
_HINGE, _BALL = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_BALL)
_FLAT = [int(mujoco.mjtGeom.mjGEOM_PLANE), int(mujoco.mjtGeom.mjGEOM_HFIELD)]
_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def _norm(name: str) -> str:
    return re.sub(r"[\s_.\-]", "", name.rsplit(":", 1)[-1]).lower()


def _tokens(name: str) -> set[str]:
    """Lower-case words of a name: split at non-letters, digits and camel case ('AAHead_yaw' -> aa, head, yaw)."""
    return {t.lower() for t in re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+", name)}


def _paired(names: list[str]) -> dict[int, set[str]]:
    """Tokens of names whose side is a bare first letter: 'lfemur' beside 'rfemur' -> {l, femur} (CMU's rig).

    Only where both sides' names are there, so a lone 'rib' or 'leg' is not taken for a side.
    """
    low = [n.lower() for n in names]
    have = set(low)
    return {i: {n[0], *_tokens(n[1:])} for i, n in enumerate(low)
            if len(n) > 2 and n[0] in "lr" and n[1].isalpha() and {"l": "r", "r": "l"}[n[0]] + n[1:] in have}


# ------------------------------------------------------------------ the source
def find_source(clip: bvh.Clip, given: dict[str, str] | None = None) -> dict[str, int]:
    """Role -> joint index in ``clip`` for the roles found: ``given`` names first, the rest by :data:`SOURCE_NAMES`.

    Raises:
        InputError: ``given`` names a role that is not one of :data:`ROLES`.
        BvhError: ``given`` names a joint the clip does not have.
    """
    found: dict[str, int] = {}
    by_norm: dict[str, int] = {}
    for i, n in enumerate(clip.names):
        by_norm.setdefault(_norm(n), i)
    for role, name in (given or {}).items():
        if role not in ROLES:
            raise InputError(f"unknown role {role!r} in the mapping; roles are: {', '.join(ROLES)}")
        found[role] = clip.index(name)
    for role in ROLES:
        if role in found:
            continue
        side, _, part = role.partition("_")
        pats = SOURCE_NAMES[part] if part else SOURCE_NAMES[role]
        for pat in pats:
            cand = pat.format(s=side, c=side[:1]) if part else pat
            if cand in by_norm and by_norm[cand] not in found.values():
                found[role] = by_norm[cand]
                break
    return found


def source_mapping(clip: bvh.Clip, given: dict[str, str] | None = None) -> dict[str, int]:
    """Role -> joint index in ``clip``: ``given`` names first, the rest found by :data:`SOURCE_NAMES`.

    Raises:
        InputError: a required role has no joint (the message lists those and the clip's joint names).
    """
    found = find_source(clip, given)
    missing = [r for r in REQUIRED if r not in found]
    if missing:
        shown = ", ".join(clip.names[:40]) + (f", ... ({len(clip.names) - 40} more)" if len(clip.names) > 40 else "")
        raise InputError(f"cannot map {', '.join(missing)} of BVH {clip.source or 'clip'} by joint names; give a "
                         f"mapping file with those roles (its joints: {shown})")
    return found


# ------------------------------------------------------------------ the figure
class _Zero:
    """A figure in its zero pose: world poses, joints, geoms' extents, sides and subtrees of its bodies.

    It keeps the tree's model, not the tree, so that :data:`_ZEROS` lets trees go.
    """

    def __init__(self, tree: Tree) -> None:
        m = tree.model
        n = m.nbody
        self.model = m
        self.names = tree.names("body")
        self.parent = np.asarray(tree.body_parent)
        self.T = tree.fk(tree.qpos0)  # (nbody, 4, 4)
        self.pos = self.T[:, :3, 3]
        self.children: list[list[int]] = [[] for _ in range(n)]
        self.depth = np.zeros(n, dtype=np.int64)
        for b in range(1, n):  # MuJoCo numbers parents before children
            self.children[self.parent[b]].append(b)
            self.depth[b] = self.depth[self.parent[b]] + 1
        self.dofs = np.asarray(m.body_dofnum, dtype=np.int64).copy()  # own dofs, then the subtree's below
        self.sub_dofs = self.dofs.copy()
        for b in range(n - 1, 0, -1):
            self.sub_dofs[self.parent[b]] += self.sub_dofs[b]
        jnames = tree.names("joint")
        self.joints: list[list[int]] = [[] for _ in range(n)]
        for j in range(m.njnt):
            self.joints[int(m.jnt_bodyid[j])].append(j)
        paired = _paired(self.names)
        self.tokens = [_tokens(self.names[b]).union(paired.get(b, set()), *(_tokens(jnames[j]) for j in self.joints[b]))
                       for b in range(n)]
        free = [int(m.jnt_bodyid[j]) for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        self.root = free[0] if free else max(self.children[0], key=lambda c: len(self.subtree(c)), default=0)
        ids = np.flatnonzero(~np.isin(m.geom_type, _FLAT))
        corners = np.einsum("gij,gkj->gki", spatial.quat_to_mat(spatial.quat_normalize(m.geom_quat[ids])),
                            m.geom_aabb[ids, None, :3] + _CORNERS * m.geom_aabb[ids, None, 3:]) + m.geom_pos[ids, None]
        owner = m.geom_bodyid[ids]
        self.geoms = [ids[owner == b].tolist() for b in range(n)]
        self.boxes = [corners[owner == b] for b in range(n)]  # (geoms, 8, 3) geom box corners in the body frame
        self.points = [self.world(b, x.reshape(-1, 3)) if len(x) else self.pos[b][None]
                       for b, x in enumerate(self.boxes)]  # (k, 3) world; a body without geoms: its origin
        body = self.subtree(self.root)
        z = np.concatenate([self.points[b][:, 2] for b in body])
        self.floor, self.height = float(z.min()), max(float(np.ptp(z)), 1e-9)
        self.lateral = (self.pos - self.pos[self.root]) @ self._left()  # (nbody,) m to the figure's left

    def _left(self) -> Array:
        """The figure's left ``(3,)`` at ``qpos0``, level: from its bodies named left to those named right.

        Else its root's y (CMU's humanoid has its root's y up, its left on the world's x).
        """
        left, right = ([b for b in range(1, len(self.pos)) if self.tokens[b] & side and not self.tokens[b] & other]
                       for side, other in ((LEFT, RIGHT), (RIGHT, LEFT)))
        if left and right:
            d = self.pos[left].mean(axis=0) - self.pos[right].mean(axis=0)
            d[2] = 0.0
            if np.linalg.norm(d) > 1e-6:
                return d / np.linalg.norm(d)
        return self.T[self.root, :3, 1]

    def world(self, b: int, local: Array) -> Array:
        """Points ``(..., 3)`` in ``b``'s frame to world."""
        return local @ self.T[b, :3, :3].T + self.pos[b]

    def subtree(self, b: int) -> list[int]:
        """``b`` and every body below it."""
        out, todo = [], [b]
        while todo:
            out.append(c := todo.pop())
            todo.extend(self.children[c])
        return out

    def path(self, top: int, b: int) -> list[int]:
        """The bodies from ``top`` (included) down to its descendant ``b``."""
        out = [b]
        while out[-1] != top:
            out.append(int(self.parent[out[-1]]))
        return out[::-1]

    def common(self, bodies: list[int]) -> int:
        """The deepest common ancestor (or self) of ``bodies``."""
        a = bodies[0]
        for b in bodies[1:]:
            while self.depth[b] > self.depth[a]:
                b = int(self.parent[b])
            while self.depth[a] > self.depth[b]:
                a = int(self.parent[a])
            while a != b:
                a, b = int(self.parent[a]), int(self.parent[b])
        return a

    def side(self, b: int) -> str | None:
        """'left'/'right' from ``b``'s (and its joints') names, else from where it is, else None."""
        left, right = bool(self.tokens[b] & LEFT), bool(self.tokens[b] & RIGHT)
        if left != right:
            return "left" if left else "right"
        if abs(self.lateral[b]) > LATERAL * self.height:
            return "left" if self.lateral[b] > 0 else "right"
        return None

    def axes(self, chain: list[int]) -> list[tuple[int, int, Array, Array | None]]:
        """The ball and hinge joints along ``chain``: (index in chain, joint, world anchor, world axis or None)."""
        m, out = self.model, []
        for k, b in enumerate(chain):
            R, p = self.T[b, :3, :3], self.pos[b]
            for j in self.joints[b]:
                if m.jnt_type[j] in (_HINGE, _BALL):
                    axis = R @ m.jnt_axis[j] if m.jnt_type[j] == _HINGE else None
                    out.append((k, j, R @ m.jnt_pos[j] + p, axis))
        return out

    def com(self, b: int) -> Array:
        """``b``'s centre of mass ``(3,)`` in its frame (zero for a body without geoms or inertial).

        MuJoCo gives such a body its own position in the parent as a centre of mass: that is not taken.
        """
        m = self.model
        if not self.geoms[b] and np.array_equal(m.body_ipos[b], m.body_pos[b]):
            return np.zeros(3)
        return np.array(m.body_ipos[b])

    def reach(self, b: int) -> Array:
        """Points ``(k, 3)`` (world) of ``b``'s extent: its geoms' corners and twice its centre of mass."""
        return np.vstack([self.points[b], self.world(b, 2 * self.com(b))])

    @cached_property
    def found(self) -> FoundFigure:
        """The roles :func:`find_figure` finds."""
        return _find(self)


_ZEROS: weakref.WeakKeyDictionary[Tree, _Zero] = weakref.WeakKeyDictionary()  # a tree's, made once: trees do not change


def _zero(tree: Tree) -> _Zero:
    if tree not in _ZEROS:
        _ZEROS[tree] = _Zero(tree)
    return _ZEROS[tree]


def _centre(axes: list[tuple[int, int, Array, Array | None]], spread: float) -> Array:
    """The joint centre ``(3,)`` (world): the point nearest (least squares) the hinge axes and ball centres.

    Axes passing more than ``spread`` (m) from it are left out, the farthest first (a clavicle's). A little pull
    toward the anchors' mean settles what the lines leave free (parallel axes, one axis).
    """
    while True:
        anchors = np.array([a for _, _, a, _ in axes])
        P = np.array([np.eye(3) if u is None else np.eye(3) - np.outer(u, u) for _, _, _, u in axes])
        x = np.linalg.solve(1e-3 * np.eye(3) + P.sum(axis=0),
                            1e-3 * anchors.mean(axis=0) + np.einsum("kij,kj->i", P, anchors))
        off = np.linalg.norm(np.einsum("kij,kj->ki", P, x - anchors), axis=1)  # each line's distance from x
        if len(axes) == 1 or off.max() <= spread:
            return x
        axes = [ax for k, ax in enumerate(axes) if k != int(np.argmax(off))]


def _middle(z: _Zero, chain: list[int], end: Array) -> int | None:
    """Index in ``chain`` of the knee's (elbow's) body: the joint far from both limb ends that bends across it.

    Each hinge scores its distance to the nearer end (the limb's first joint, ``end``) times how far its axis is
    from lying along either segment it joins (from its body's parent, to ``end``): a twist scores 0, a ball bends
    every way. None: no joint scores.
    """
    axes = z.axes(chain)
    if not axes:
        return None
    start = axes[0][2]

    def score(k: int, a: Array, u: Array | None) -> float:
        up, down = a - (z.pos[chain[k - 1]] if k else start), end - a
        bend = 1.0 if u is None else 1.0 - max(abs(float(u @ v)) / max(float(np.linalg.norm(v)), 1e-12)
                                               for v in (up, down))
        return min(float(np.linalg.norm(a - start)), float(np.linalg.norm(down))) * bend

    scores = [score(k, a, u) for k, _, a, u in axes]
    best = int(np.argmax(scores))
    return axes[best][0] if scores[best] > 1e-6 * z.height else None


def _arm_end(z: _Zero, chain: list[int]) -> Array:
    """Where the arm ``chain`` ends, for finding its elbow: the farthest point of its geoms from its first body.

    But where the body farthest out has no joint (a hand fixed past the wrist's joints), that body's origin: a
    robot's hand mesh reaching 0.2 m past its wrist (GMR's G1) made the wrist the arm's middle joint.
    """
    start, bodies = z.pos[chain[0]], z.subtree(chain[0])
    hand = bodies[int(np.argmax(np.linalg.norm(z.pos[bodies] - start, axis=1)))]
    if not z.dofs[hand]:
        return z.pos[hand]
    tips = np.vstack([z.reach(b) for b in bodies])
    return tips[np.argmax(np.linalg.norm(tips - start, axis=1))]


def _nearest(z: _Zero, bodies: list[int], point: Array) -> int:
    return bodies[int(np.argmin(np.linalg.norm(z.pos[bodies] - point, axis=1)))]


def _limb(z: _Zero, chain: list[int], end: Array, parts: tuple[str, str, str], side: str,
          hand: bool) -> dict[str, int]:
    """Roles of one limb ``chain`` (root to end): the upper joint centre's body, the middle joint's, the last.

    The last is the chain's end body for a leg; for an arm (``hand``) the body at the centre of the joints past
    the elbow, else the body after the elbow (a hand without joints), else the elbow's own body.
    """
    km = _middle(z, chain, end)
    if km is None or km == 0:
        return {}
    axes = z.axes(chain)
    upper = [x for x in axes if x[0] < km]
    top = _nearest(z, chain[:km], _centre(upper, CENTRE_SPREAD * z.height)) if upper else chain[0]
    lower, after = [x for x in axes if x[0] > km], chain[km + 1:]
    if not hand:
        last = chain[-1]
    elif lower:
        last = _nearest(z, after, _centre(lower, CENTRE_SPREAD * z.height))
    else:
        last = after[0] if after else chain[km]
    return dict(zip((f"{side}_{p}" for p in parts), (top, chain[km], last), strict=True))


def _legs(z: _Zero) -> tuple[int | None, dict[str, list[int]]]:
    """The pelvis and, per side, the leg chain from below the pelvis down to the foot (the last body with a sole).

    Soles are the geoms within :data:`SOLE_BAND` of the figure's lowest point; the pelvis is their bodies' deepest
    common ancestor; the legs are the two of its children with soles below that lie farthest apart (y). A toe
    (named so) is never the foot, nor a body without a joint when the leg has soles on one with.
    """
    band = [b for b in z.subtree(z.root) if z.geoms[b] and z.points[b][:, 2].min() <= z.floor + SOLE_BAND * z.height]
    if not band:
        return None, {}
    pelvis = z.common(band)
    branches: dict[int, list[int]] = {}
    for b in band:
        if b != pelvis:
            branches.setdefault(z.path(pelvis, b)[1], []).append(b)
    if len(branches) < 2:
        return pelvis, {}
    by_y = sorted(branches, key=lambda c: float(np.mean(z.lateral[branches[c]])))
    legs = []
    for top in (by_y[-1], by_y[0]):  # left (+y) first
        feet = [b for b in branches[top] if not z.tokens[b] & TOES] or branches[top]
        feet = [b for b in feet if z.dofs[b]] or feet  # not a welded contact point below the foot
        legs.append(z.path(top, max(feet, key=lambda b: z.depth[b])))
    return pelvis, dict(zip(SIDES, _sided(z, legs), strict=True))


def _sided(z: _Zero, chains: list[list[int]]) -> list[list[int]]:
    """Two chains, left then right: by their names' majority if those differ, else as given (left on +y)."""
    votes = []
    for chain in chains:
        sides = [s for s in (z.side(b) for b in chain) if s]
        votes.append(max(SIDES, key=sides.count) if sides and sides.count("left") != sides.count("right") else None)
    return chains[::-1] if votes == ["right", "left"] else chains


def _arm(z: _Zero, side: str, skip: set[int]) -> list[int]:
    """The arm chain of ``side``, from its shallowest body (not in ``skip``) with two or more dofs below.

    It follows the child with dofs below it and ends where the arm branches (fingers) or at a hand without joints.
    """
    cands = [b for b in z.subtree(z.root) if b not in skip and b != z.root and z.sub_dofs[b] >= 2
             and z.side(b) == side]
    if not cands:
        return []
    chain = [min(cands, key=lambda b: (z.depth[b], -z.sub_dofs[b]))]
    while True:
        kids = z.children[chain[-1]]
        moving = [c for c in kids if z.sub_dofs[c] > 0]
        if len(moving) == 1:
            chain.append(moving[0])
            continue
        if not moving and len(kids) == 1:
            chain.append(kids[0])
        return chain


def _head(z: _Zero, torso: int, skip: set[int]) -> int:
    """The head: the deepest body above the torso's origin (not in ``skip``) named a head or neck.

    Else the deepest such body near the midline that a joint below the torso moves; else the torso itself.
    """
    up = [b for b in z.subtree(torso) if b != torso and b not in skip and z.pos[b, 2] > z.pos[torso, 2]]
    named = [b for b in up if z.tokens[b] & HEADS]
    moved = [b for b in up if abs(z.lateral[b]) <= LATERAL * z.height and any(z.dofs[c] for c in z.path(torso, b)[1:])]
    pick = named or moved
    return max(pick, key=lambda b: (z.depth[b], z.pos[b, 2])) if pick else torso


@dataclass(frozen=True)
class FoundFigure:
    """What :func:`find_figure` made of a figure.

    ``bodies``: role -> body name for the roles found (:data:`FIGURE_ROLES`); ``missing``: the required roles it
    could not find; ``candidates``: the bodies with a joint outside the limbs found that no role took, those of a
    missing role's side first: the ones that might fit.
    """

    bodies: dict[str, str]
    missing: tuple[str, ...]
    candidates: tuple[str, ...]


def find_figure(tree: Tree) -> FoundFigure:
    """The figure's roles from its tree at ``qpos0`` (no table of model names).

    Legs: the two chains from the pelvis (the common ancestor of the bodies with soles, their geoms within
    :data:`SOLE_BAND` of the lowest point) down to those bodies. Arms: per side, the shallowest body off the
    legs on that side (by ``left``/``l``/``right``/``r`` name tokens, else by where it is) with two or more dofs
    below it, down to where it branches into fingers. The knee (elbow) is the body of the limb's middle bending
    joint; the hip (shoulder) the chain body nearest the point closest to the joint axes above it (their
    centre: a three-body hip maps to the body there); the ankle the last leg body with a sole (not a toe); the
    wrist the body at the centre of the joints past the elbow, else the body after the elbow (a hand without
    joints), else the elbow's body (its point then at the far end: :func:`role_offsets`). The torso is the arms'
    deepest common ancestor; the head the deepest body above it named ``head``/``neck``, else the deepest
    midline one a joint moves, else the torso (:func:`role_offsets` puts its point above the shoulders).
    """
    found = _zero(tree).found
    return replace(found, bodies=dict(found.bodies))


def _find(z: _Zero) -> FoundFigure:
    found: dict[str, int] = {}
    pelvis, legs = _legs(z)
    skip = {b for chain in legs.values() for b in z.subtree(chain[0])}
    if pelvis is not None:
        found["pelvis"] = pelvis
    limbs: set[int] = set()  # the bodies of limbs whose roles were found
    for s, chain in legs.items():
        roles = _limb(z, chain, z.pos[chain[-1]], ("hip", "knee", "ankle"), s, hand=False)
        found.update(roles)
        limbs |= set(z.subtree(chain[0])) if roles else set()
    arms = [_arm(z, s, skip) for s in SIDES]
    for s, chain in zip(SIDES, arms, strict=True):
        if chain:
            end = _arm_end(z, chain)
            roles = _limb(z, chain, end, ("shoulder", "elbow", "wrist"), s, hand=True)
            found.update(roles)
            limbs |= set(z.subtree(chain[0])) if roles else set()
    roots = [chain[0] for chain in arms if chain]
    if roots:
        found["torso"] = z.common(roots) if len(roots) == 2 else int(z.parent[roots[0]])
        skip |= {b for r in roots for b in z.subtree(r)}
        found["head"] = _head(z, found["torso"], skip)
    missing = tuple(r for r in FIGURE_ROLES if r not in found)
    sides = {r.partition("_")[0] for r in missing}
    free = sorted((b for b in z.subtree(z.root) if b not in limbs and b not in found.values() and z.dofs[b]),
                  key=lambda b: (z.side(b) not in sides, b))  # a missing side's bodies first
    return FoundFigure({r: z.names[b] for r, b in found.items()}, missing, tuple(z.names[b] for b in free))


def _check_figure(tree: Tree, given: dict[str, str]) -> None:
    """Raise for a role of ``given`` that no figure has, or a body ``tree`` does not have."""
    for role, body in given.items():
        if role not in FIGURE_ROLES:
            raise InputError(f"unknown figure role {role!r} in the mapping; roles are: {', '.join(FIGURE_ROLES)}")
        tree.id(body, "body")  # UnknownNameError lists the bodies


def figure_mapping(tree: Tree, given: dict[str, str] | None = None) -> dict[str, str]:
    """Role -> body of ``tree`` for :data:`FIGURE_ROLES`: ``given`` first, the rest found (:func:`find_figure`).

    Raises:
        InputError: ``given`` names an unknown role, or a role has no body (the one line names the roles missing
            and bodies that might fit them).
        UnknownNameError: ``given`` names a body the model does not have.
    """
    given = given or {}
    _check_figure(tree, given)
    found = find_figure(tree)
    bodies = {r: given.get(r, found.bodies.get(r)) for r in FIGURE_ROLES}
    missing = [r for r, b in bodies.items() if b is None]
    if missing:
        maybe = ", ".join(found.candidates[:12]) + (", ..." if len(found.candidates) > 12 else "") or "none"
        raise InputError(f"cannot find the retargeting roles {', '.join(missing)} of model {tree.name!r} (bodies "
                         f"that might fit: {maybe}); give them in the mapping file's \"figure\" object (role -> "
                         f"body; mjkin retarget --print-mapping writes one to fill in)")
    return {r: b for r, b in bodies.items() if b is not None}


# ------------------------------------------------------------------ points on the figure
def role_offsets(tree: Tree, bodies: dict[str, str]) -> dict[str, Array]:
    """Each role's point ``(3,)`` in its body's frame (m): the body origin, but for heads and wrists without one.

    A head on the torso's body (no head body): the centre of the torso's highest geom if that is centred above
    the shoulders and reaches :data:`HEAD_REACH` shoulder spans above them, else :data:`HEAD_ABOVE` spans above
    the shoulders' midpoint. A wrist body that carries the fingers (two or more children with joints) holds the
    hand: where the fingers attach (their origins' mean). A wrist on the elbow's body (nothing past the elbow):
    the far end of that body (its geoms or twice its centre of mass, along their direction from the origin).
    """
    z = _zero(tree)
    ids = {r: tree.id(b, "body") for r, b in bodies.items()}
    out = {r: np.zeros(3) for r in bodies}
    torso = ids.get("torso")
    if torso is not None and ids.get("head") == torso:
        sh = z.pos[[ids["left_shoulder"], ids["right_shoulder"]]]
        mid, span = sh.mean(axis=0), float(np.linalg.norm(sh[0] - sh[1]))
        point = mid + np.array([0.0, 0.0, HEAD_ABOVE * span])
        boxes = z.world(torso, z.boxes[torso])  # (geoms, 8, 3)
        centres, tops = boxes.mean(axis=1), boxes[..., 2].max(axis=1)
        high = (centres[:, 2] > mid[2]) & (tops - mid[2] >= HEAD_REACH * span)
        if high.any():
            point = centres[high][np.argmax(tops[high])]
        out["head"] = z.T[torso, :3, :3].T @ (point - z.pos[torso])
    for s in SIDES:
        b = ids.get(f"{s}_wrist")
        fingers = [] if b is None else [c for c in z.children[b] if z.sub_dofs[c]]
        if len(fingers) >= 2:
            out[f"{s}_wrist"] = tree.body_pos[fingers].mean(axis=0)
        elif b is not None and b == ids.get(f"{s}_elbow"):
            com = 2 * z.com(b)
            d = com + (z.boxes[b].mean(axis=(0, 1)) if len(z.boxes[b]) else 0.0)
            d = d / max(float(np.linalg.norm(d)), 1e-12)
            out[f"{s}_wrist"] = d * max(float((np.vstack([z.boxes[b].reshape(-1, 3), com]) @ d).max()), 0.0)
    return out


def pelvis_lean(tree: Tree, bodies: dict[str, str]) -> float:
    """The share of the source's lean (pelvis to shoulders, from upright) the pelvis takes.

    :data:`WAIST_LEAN` if a joint between the pelvis and the torso can pitch the torso (a ball, or a hinge about
    the figure's y, turning :data:`PITCH_RANGE` or more), else 1: a torso that turns only about the vertical
    cannot take any of it.
    """
    z = _zero(tree)
    pelvis, torso = tree.id(bodies["pelvis"], "body"), tree.id(bodies["torso"], "body")
    top = z.common([pelvis, torso])
    between = set(z.path(top, pelvis)[1:]) | set(z.path(top, torso)[1:])
    y = z.T[z.root, :3, 1]
    m = tree.model
    for b in between:
        for j in z.joints[b]:
            turn = float(m.jnt_range[j, 1] if m.jnt_type[j] == _BALL else np.ptp(m.jnt_range[j]))
            pitches = m.jnt_type[j] == _BALL or (m.jnt_type[j] == _HINGE
                                                and abs(float(z.T[b, :3, :3] @ m.jnt_axis[j] @ y)) > 0.7)
            if pitches and (not m.jnt_limited[j] or turn >= PITCH_RANGE):
                return WAIST_LEAN
    return 1.0


# ------------------------------------------------------------------ mapping files
def read_mapping(path: str | os.PathLike[str]) -> dict[str, dict[str, str]]:
    """A mapping file: ``{"source": {role: bvh joint}, "figure": {role: body}}``, either part optional.

    Raises:
        MjkinIOError: missing or not JSON.
        InputError: not of that shape.
    """
    text = files.read_input_text(path, "mapping file", files.LIMITS["mapping"])
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise MjkinIOError(f"cannot read mapping {str(path)!r}: {' '.join(str(e).split()) or 'nested too deeply'}") \
            from None
    if not isinstance(doc, dict) or set(doc) - {"source", "figure"} or not all(
            isinstance(v, dict) and all(isinstance(a, str) and isinstance(b, str) for a, b in v.items())
            for v in doc.values()):
        raise InputError(f"mapping {str(path)!r} must be {{\"source\": {{role: joint}}, \"figure\": {{role: body}}}} "
                         f"with string names; roles: {', '.join(ROLES)}")
    return {k: dict(v) for k, v in doc.items()}


def found_mapping(clip: bvh.Clip, tree: Tree, given: dict[str, dict[str, str]] | None = None
                  ) -> tuple[dict[str, dict[str, str]], list[str]]:
    """A mapping file's content for ``clip`` onto ``tree``, both parts filled with what was found.

    ``given`` comes first. Also returns the required roles still missing (``"source: left_knee"``,
    ``"figure: head"``).

    Raises:
        InputError, BvhError, UnknownNameError: ``given`` names unknown roles, joints or bodies.
    """
    given = given or {}
    joints = find_source(clip, given.get("source"))
    source = {r: clip.names[joints[r]] for r in ROLES if r in joints}
    _check_figure(tree, given.get("figure", {}))
    found = find_figure(tree).bodies | given.get("figure", {})
    figure = {r: found[r] for r in FIGURE_ROLES if r in found}
    missing = [f"source: {r}" for r in REQUIRED if r not in source]
    missing += [f"figure: {r}" for r in FIGURE_ROLES if r not in figure]
    return {"source": source, "figure": figure}, missing
