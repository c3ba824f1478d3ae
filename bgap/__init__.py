"""bgap: behaviour-rich traffic simulation, CMetric and behaviour-aware navigation (B-GAP).

Importing ``bgap`` registers the gymnasium environment ``bgap/BehaviorHighway-v0`` (as
``import highway_env`` registers highway-env's) and loads nothing else but gymnasium: the
environment's module, highway-env, torch and Hydra are imported when first used, so
``bgap.cmetric`` stays light.
"""

import os

import gymnasium as gym

# Same seed, same numbers on any x86 CPU: torch picks its CPU kernels by the instruction set
# it finds (AVX-512 or AVX2 vectorised loops, MKL's per-ISA GEMM paths), and their float
# sums differ in the last bits, which a training amplifies (the same 6,000-step training
# ends with other weights on an AVX-512 machine than on the one the study was trained on).
# Set before torch is imported, unless the user set them. Measured cost: about 10% of an
# SB3 training (small networks); 4.5x for the batched learner's stacked products
# (docs/benchmarks.md).
os.environ.setdefault("ATEN_CPU_CAPABILITY", "default")
os.environ.setdefault("MKL_CBWR", "COMPATIBLE")

__version__ = "0.1.0"

ENV_ID = "bgap/BehaviorHighway-v0"
"""The behaviour-rich highway: ``gym.make(ENV_ID, config={...})``."""

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="bgap.envs.highway:BehaviorHighwayEnv")
