"""The demo's scenes: each renders on its own, with captions, at the asked size and length."""

from __future__ import annotations

import numpy as np
import pytest

import mjkin
from mjkin import motion, render
from mjkin.apps.demo import showcase
from mjkin.scene import Scene


@pytest.mark.parametrize("scene", ["seeds", "arm", "walk"])
def test_each_scene_renders_and_moves(scene):
    images = np.stack(list(showcase.showcase(scene, seconds=0.4, fps=20, width=160, height=120)))
    assert images.ndim == 4 and images.shape[1:] == (120, 160, 3) and len(images) >= 8
    assert images.std() > 10 and not np.array_equal(images[0], images[-1])


def test_scene_names_and_lengths():
    with pytest.raises(mjkin.InputError, match="unknown demo scene 'nope'"):
        showcase.showcase("nope")
    with pytest.raises(mjkin.InputError, match="must be positive"):
        showcase.showcase("seeds", seconds=0)
    assert sum(showcase.SHARES.values()) == pytest.approx(1.0)


def test_the_arm_path_clears_the_obstacles():
    tree = showcase.arm_with_obstacles()
    home = tree.model.key_qpos[0]
    path = motion.waypoints(np.vstack([tree.pose(home, "ee")[:3, 3], showcase.ARM_STOPS]), 200, corner=0.12)
    gaps = np.linalg.norm(path[:, None] - showcase.OBSTACLES[None, :, :3], axis=-1) - showcase.OBSTACLES[:, 3]
    assert gaps.min() > 0.05  # the effector path passes the obstacles with room to spare
    assert not Scene(tree).in_collision(home)


def test_the_arm_scene_moves_without_contacts():
    """The arm's links keep clear of the obstacles and of each other on every frame (the caption's "contacts 0")."""
    n = showcase.scene_frames("arm")["arm"]
    tree, path, traj = showcase.arm_motion(n, 30.0)
    scene = Scene(tree)
    assert traj.success.all()
    assert [k for k, q in enumerate(traj.q) if scene.contacts(q)] == []
    assert np.linalg.norm(tree.pose(traj.q, "ee")[:, :3, 3] - path, axis=-1).max() < 1e-4


@pytest.mark.parametrize("width, height", [(320, 240), (400, 240)])
def test_the_walk_caption_leaves_the_head_in_view(width, height):
    """The caption's band covered the primate's head (its lines reached past the middle, where the camera keeps it)."""
    tree, qs, caption = showcase.walk_motion(24, 30.0)
    images = list(showcase.scene_walk(width, height, 24, 30.0))
    cams = render.camera_path(tree, qs, aspect=width / height, view=render.WALK_VIEW, follow=True)  # as frames() does
    head = tree.id("head", "body")
    radius = max(tree.model.geom_rbound[tree.model.geom_bodyid == head])
    centres = tree.fk(qs)[:, head, :3, 3]
    for t, (image, cam) in enumerate(zip(images, cams, strict=True)):
        (x, y), = render.project(tree, cam, centres[t], width, height)
        (edge_x, _), = render.project(tree, cam, centres[t] + (radius, 0, 0), width, height)  # world x: to the right
        r = edge_x - x  # the head's radius in pixels
        assert r > 2 and 0 < x < width and 0 < y < height
        red, _, blue = image[round(y), round(x)].astype(int)
        assert red > 1.3 * blue  # the brown head there, not the blue sky (blue over red)
        left, top, right, bottom = render.caption_box(height, width, caption(t))
        gap_x, gap_y = max(left - x, x - right, 0.0), max(top - y, y - bottom, 0.0)
        assert np.hypot(gap_x, gap_y) > r, f"frame {t}: the caption covers the head"
