"""What a new user sees (issue 54): the reach envs' targets and one staged look, hidden shapes, timeouts told."""

from __future__ import annotations

import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import mjkin
import mjkin.envs  # noqa: F401  (registers the gymnasium environments)
from conftest import shared, tree_of
from mjkin import render

W, H = 240, 180
ENVS = ["mjkin/Reach-v0", "mjkin/PlanarReach-v0", "mjkin/PandaReach-v0"]
DOCS = Path(__file__).resolve().parents[2] / "docs"


def env_frame(env_id: str, width: int = W, height: int = H, **options: object) -> tuple[np.ndarray, gym.Env]:
    env = gym.make(env_id, render_mode="rgb_array", width=width, height=height)
    env.reset(seed=0, options=options or None)
    frame = env.render()
    env.close()
    return frame, env.unwrapped


def red(image: np.ndarray) -> np.ndarray:
    """``(H, W)``: pixels of the target marker's red (lit or shaded)."""
    rgb = image.astype(int)
    return (rgb[..., 0] > 120) & (rgb[..., 0] > 2 * rgb[..., 1]) & (rgb[..., 0] > 2 * rgb[..., 2])


def test_the_planar_arm_shows_its_target():
    """The marker was 3 cm across in a world 30 units wide: not one pixel of it was drawn."""
    target = np.array([-15.0, 10.0, 0.0])  # clear of the arm, which starts stretched along +x
    frame, env = env_frame("mjkin/PlanarReach-v0", 480, 360, target=target)  # the env's frame size
    col, row = render.project(env.tree, env._camera, target[None], 480, 360)[0].round().astype(int)
    around = red(frame)[row - 15:row + 16, col - 15:col + 16]
    assert around[15, 15] and around.sum() > 50  # a ball of some pixels where the target is
    assert env._marker.point_size >= mjkin.envs.reach.MARKER * env.extent


@pytest.mark.parametrize("env_id", ENVS)
def test_reach_envs_are_staged_alike(env_id):
    """A black sky (Panda), a washed-out white floor seen from above (planar) and a grey one (arm7) before."""
    frame, _ = env_frame(env_id)
    rgb = frame.astype(int)
    assert (rgb.min(-1) > 220).mean() < 0.02  # not washed out
    assert (rgb.max(-1) < 25).mean() < 0.02  # no black sky
    floor = rgb[-12:, :12].reshape(-1, 3)  # the bottom-left corner: the checker floor
    assert (floor[:, 2] - floor[:, 0] > 25).all()  # blue, as every staged model's


def test_the_reach_envs_share_one_sky():
    skies = [env_frame(env_id)[0][:6, :6].reshape(-1, 3).mean(0) for env_id in ("mjkin/Reach-v0",
                                                                                  "mjkin/PandaReach-v0")]
    assert np.abs(skies[0] - skies[1]).max() < 15 and skies[0][2] > skies[0][0] + 15  # the same blue gradient


# a body whose only shape is a collision geom (group 3, not drawn by default), and one with a visible geom
# beside a hidden one (that stays hidden)
HIDDEN = """<mujoco><worldbody><light pos="0 0 3" dir="0 0 -1" directional="true"/>
<body name="shin" pos="0 0 0.5"><joint name="a" axis="0 1 0"/>
<geom name="collision" type="box" size="0.05 0.05 0.2" pos="0 0 -0.25" group="3" rgba="0.2 0.8 0.2 1"/>
<body name="arm" pos="0.3 0 0"><joint name="b" axis="0 1 0"/>
<geom name="shown" type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" rgba="0.8 0.8 0.8 1"/>
<geom name="hidden" type="box" size="0.1 0.1 0.1" pos="0.15 0 0" group="3" rgba="0.8 0.2 0.8 1"/>
</body></body></worldbody></mujoco>"""


def test_a_body_with_nothing_visible_shows_its_collision_geoms():
    """A robot whose real shapes are only in its collision geoms showed as a stick figure."""
    tree = tree_of(HIDDEN)
    m, q = tree.model, np.zeros(2)
    shown = render.shown_geoms(m)
    assert shown.tolist() == [True, True, False]  # the shin's box; not the arm's hidden box
    with render.Painter(tree, W, H) as painter:
        cam = painter.camera(None, q[None])
        image = painter.draw(q, cam).astype(int)
    green = (image[..., 1] > image[..., 0] + 40) & (image[..., 1] > image[..., 2] + 40)
    magenta = (image[..., 0] > image[..., 1] + 40) & (image[..., 2] > image[..., 1] + 40)
    col, row = render.project(tree, cam, [[0.0, 0.0, 0.25]], W, H)[0].round().astype(int)  # the box's centre
    assert green[row, col] and green.sum() > 200
    assert magenta.sum() == 0
    assert render.bare_links(m).tolist() == [[1, 2]]  # nothing visible runs from the shin's origin to the arm's


G1 = [p for p in shared() if p.stem == "g1"]


@pytest.mark.skipif(not G1, reason="the shared mesh-free robot models are not here")
def test_the_mesh_free_g1_shows_its_collision_shapes():
    model = mjkin.load(G1[0]).model
    ids = render.figure_geoms(model)
    revealed = {model.body(b).name for b in model.geom_bodyid[ids[model.geom_group[ids] >= 3]]}
    assert {"left_knee_link", "left_ankle_roll_link", "right_shoulder_roll_link"} <= revealed


def test_the_statuses_say_where_an_interpreted_run_differs():
    """A timed-out solve's interpreted first run said ``timeout`` after 135 restarts, the compiled ``max_iterations``
    after 1 000, and nothing said why.
    """
    page = (DOCS / "concepts" / "results.md").read_text()
    section = re.search(r"## Time limits and the first run\n(.*?)\n## ", page, re.S)
    assert section is not None
    text = " ".join(section.group(1).split())
    for said in ("interpreted", "`timeout`", "`max_iterations`", "MJKIN_COMPILE=wait"):
        assert said in text
