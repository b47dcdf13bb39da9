"""gymnasium environments driven by mjkin, registered on import.

``mjkin/Reach-v0``: the bundled 7-DoF arm reaches 3-D targets.
``mjkin/PlanarReach-v0``: the seeds' planar three-link arm (15/10/5) reaches targets in its plane.
Both take ``action_type="joint"`` (default) or ``"cartesian"``; see :class:`ReachEnv`.
"""

from gymnasium.envs.registration import register, registry

from .reach import ReachEnv, ik_expert

__all__ = ["ReachEnv", "ik_expert"]

for _id, _kwargs in (("mjkin/Reach-v0", {"model": "arm7", "site": "ee"}),
                     ("mjkin/PlanarReach-v0", {"model": "planar_3link", "site": "tip"})):
    if _id not in registry:
        register(id=_id, entry_point="mjkin.envs.reach:ReachEnv", max_episode_steps=100, kwargs=_kwargs)
