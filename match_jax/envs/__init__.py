"""The simulation and env layer: fragile peg-in-hole (FR3 arm, peg, hole) in MuJoCo-MJX, with the MJX
plumbing (`sim`), the wrist sensor, model randomisation, the control laws and action spaces
(`controllers`), the task presets, scripted baselines and physics probes. The lowest layer: it imports
nothing else from match_jax."""

from match_jax.envs.fpih import PHASE_APPROACH, PHASE_CONTACT, PHASE_INSERTION, FPiHConfig, FPiHEnv
from match_jax.envs.wrappers import AutoResetEnv

__all__ = ["AutoResetEnv", "FPiHConfig", "FPiHEnv", "PHASE_APPROACH", "PHASE_CONTACT", "PHASE_INSERTION"]
