"""Environments: fragile peg-in-hole (FR3 arm, peg, hole) in MuJoCo-MJX."""

from match_jax.envs.fpih import PHASE_APPROACH, PHASE_CONTACT, PHASE_INSERTION, FPiHConfig, FPiHEnv
from match_jax.envs.wrappers import AutoResetEnv

__all__ = ["AutoResetEnv", "FPiHConfig", "FPiHEnv", "PHASE_APPROACH", "PHASE_CONTACT", "PHASE_INSERTION"]
