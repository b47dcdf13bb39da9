"""Write ``models/panda.xml``: a Franka Emika Panda from its published modified-DH table.

    python examples/build_panda.py [-o models/panda.xml]

The chain is :func:`mjkin.build.dh_chain` of the table below (Craig convention,
Franka's documentation); this script then gives the links capsules sized like
the real ones, a base, a ``flange`` site 0.107 m along joint 7's axis, the joint
limits and the ``home`` keyframe, through ``mujoco.MjSpec``.
"""

from __future__ import annotations

import argparse
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np

from mjkin.kinematics.build import dh_chain
from mjkin.runtime.files import atomic_path

# (a, alpha, d, theta) per joint, metres and radians (Franka: a, d, alpha)
DH = np.array([[0.0, 0.0, 0.333, 0.0],
               [0.0, -np.pi / 2, 0.0, 0.0],
               [0.0, np.pi / 2, 0.316, 0.0],
               [0.0825, np.pi / 2, 0.0, 0.0],
               [-0.0825, -np.pi / 2, 0.384, 0.0],
               [0.0, np.pi / 2, 0.0, 0.0],
               [0.088, np.pi / 2, 0.0, 0.0]])
FLANGE = 0.107  # along z of frame 7
LIMITS = [(-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
          (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973)]
HOME = [0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4]
# capsules (from, to, radius) in each link's DH frame, after the real links' collision shapes
CAPSULES = {
    "link1": [((0, 0, -0.105), (0, 0, -0.04), 0.06)],
    "link2": [((0, 0, -0.04), (0, 0, 0.04), 0.06), ((0, 0, 0), (0, -0.15, 0), 0.06)],
    "link3": [((0, 0, -0.12), (0, 0, -0.03), 0.06), ((0.01, 0, 0), (0.0825, 0, 0), 0.055)],
    "link4": [((0, 0, -0.04), (0, 0, 0.04), 0.055), ((-0.01, 0.02, 0), (-0.0825, 0.09, 0), 0.055)],
    "link5": [((0, 0, -0.27), (0, 0, -0.13), 0.05), ((0, 0.06, -0.12), (0, 0.06, -0.04), 0.035)],
    "link6": [((0, 0, -0.03), (0, 0, 0.01), 0.045), ((0.02, 0, 0), (0.088, 0, 0), 0.04)],
    "link7": [((0, 0, 0.04), (0, 0, 0.09), 0.045)],
}
BASE = ((0, 0, 0.0), (0, 0, 0.09), 0.07)


def panda_spec() -> mujoco.MjSpec:
    """The Panda as an MjSpec: the DH chain plus geometry, flange site, limits and keyframe."""
    spec = mujoco.MjSpec.from_string(dh_chain(DH, convention="modified", ranges=LIMITS, name="panda"))
    spec.stat.extent = 1.2
    spec.stat.center = [0.3, 0.0, 0.4]
    floor = spec.geom("floor")
    floor.size = [1.5, 1.5, 0.05]
    floor.pos = [0, 0, 0]
    gray, white = [0.35, 0.35, 0.38, 1.0], [0.92, 0.92, 0.92, 1.0]
    spec.worldbody.add_geom(name="link0", type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[*BASE[0], *BASE[1]],
                            size=[BASE[2], 0, 0], rgba=white)
    for i, (name, capsules) in enumerate(CAPSULES.items()):
        body = spec.body(name)
        for g in list(body.geoms):
            spec.delete(g)
        for k, (a, b, r) in enumerate(capsules):
            body.add_geom(name=name if k == 0 else f"{name}_{k}", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                          fromto=[*a, *b], size=[r, 0, 0], rgba=white if (i + k) % 2 == 0 else gray)
    spec.site("ee").size = [0.02, 0, 0]
    link7 = spec.body("link7")
    link7.add_site(name="flange", pos=[0, 0, FLANGE], size=[0.015, 0, 0], rgba=[0.9, 0.2, 0.2, 1])
    key = spec.add_key()
    key.name, key.qpos = "home", HOME
    return spec


def main() -> None:
    """Write the model file."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[1] / "models" / "panda.xml"
    ap.add_argument("-o", "--output", type=Path, default=default, help="where to write the MJCF")
    args = ap.parse_args()
    root = ET.fromstring(panda_spec().to_xml())
    root.find("keyframe/key").set("qpos", " ".join(repr(float(x)) for x in HOME))  # to_xml keeps 6 digits
    ET.indent(root)
    text = "<!-- Franka Emika Panda from its modified-DH table; written by examples/build_panda.py -->\n" \
        + ET.tostring(root, encoding="unicode") + "\n"
    with atomic_path(args.output) as tmp:
        Path(tmp).write_text(text)
    print(args.output)


if __name__ == "__main__":
    main()
