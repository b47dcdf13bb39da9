"""gymnasium environments driven by mjkin, registered on import.

``mjkin/Reach-v0``: the bundled 7-DoF arm reaches 3-D targets.
``mjkin/PlanarReach-v0``: the seeds' planar three-link arm (15/10/5) reaches targets in its plane.
``mjkin/PandaReach-v0``: a Franka Emika Panda (modified-DH model ``panda``) reaches with its ``flange``.
All take the arguments of :class:`ReachEnv` (``action_type``, ``goal_type``, ``goal_conditioned``,
``obstacles``, ...); ``gym.make_vec(id, n, vectorization_mode="vector_entry_point")`` gives the native
batched :class:`ReachVectorEnv`.
"""

from gymnasium.envs.registration import register, registry

from .reach import ReachEnv, ik_expert
from .vector import ReachVectorEnv

__all__ = ["ReachEnv", "ReachVectorEnv", "ik_expert"]

IDS = {"mjkin/Reach-v0": {"model": "arm7", "frame": "ee"},
       "mjkin/PlanarReach-v0": {"model": "planar_3link", "frame": "tip"},
       "mjkin/PandaReach-v0": {"model": "panda", "frame": "flange"}}

for _id, _kwargs in IDS.items():
    if _id not in registry:
        register(id=_id, entry_point="mjkin.envs.reach:ReachEnv", vector_entry_point="mjkin.envs.vector:ReachVectorEnv",
                 max_episode_steps=100, kwargs=_kwargs)
