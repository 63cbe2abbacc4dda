"""Both envs satisfy the trainer's env contract; an env missing a key is named in a one-line error."""

import jax
import jax.numpy as jnp
import pytest

from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.contract import INFO_KEYS, check_env
from match_jax.envs.point_mass import PointMassEnv
from match_jax.rl.ppo import make_trainer
from match_jax.training.presets import get_preset


def test_point_mass_and_fpih_satisfy_the_contract():
    check_env(PointMassEnv())
    check_env(FPiHEnv(FPiHConfig(control="pose")))


def test_a_missing_info_key_is_named():
    class NoContact(PointMassEnv):
        def reset(self, rng):
            state = super().reset(rng)
            return state.replace(info={k: v for k, v in state.info.items() if k != "contact_axes"})

    with pytest.raises(ValueError, match="contact_axes"):
        check_env(NoContact())

    class WrongShape(PointMassEnv):
        def step(self, state, action):
            out = super().step(state, action)
            return out.replace(info={**out.info, "contact_axes": jnp.zeros(2)})

    with pytest.raises(ValueError, match=r"expected \(3,\)"):
        check_env(WrongShape())
    assert "contact_axes" in INFO_KEYS and "broken" in INFO_KEYS
    # the trainer checks the states it traces: the same error, before anything compiles
    trainer = make_trainer(get_preset("tiny", method="pose"), NoContact())
    with pytest.raises(ValueError, match="NoContact.reset state lacks .*contact_axes"):
        jax.eval_shape(trainer.init, jax.ShapeDtypeStruct((1, 2), jnp.uint32))
    with pytest.raises(ValueError, match="lacks reset/step"):
        make_trainer(get_preset("tiny", method="pose"), object())
