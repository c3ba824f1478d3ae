"""bgap: behaviour-rich traffic simulation, CMetric and behaviour-aware navigation (B-GAP).

Importing ``bgap`` registers the gymnasium environment ``bgap/BehaviorHighway-v0`` (as
``import highway_env`` registers highway-env's) and loads nothing else but gymnasium: the
environment's module, highway-env, torch and Hydra are imported when first used, so
``bgap.cmetric`` stays light.
"""

import gymnasium as gym

__version__ = "0.1.0"

ENV_ID = "bgap/BehaviorHighway-v0"
"""The behaviour-rich highway: ``gym.make(ENV_ID, config={...})``."""

if ENV_ID not in gym.registry:
    gym.register(
        id=ENV_ID,
        entry_point="bgap.envs.highway:BehaviorHighwayEnv",  # gym.make: highway-env, one env
        vector_entry_point="bgap.sim.simulators:make_vec_highway",  # gym.make_vec: vector
    )
