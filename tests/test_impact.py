"""Contact softness (`FPiHConfig.contact_timeconst`) and the impact benchmark's first-contact analysis."""

import dataclasses
import importlib.util
import json
import math
import pathlib

import numpy as np
import pytest

from match_jax.envs import sim
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.training.runs import RunSpec

REPO = pathlib.Path(__file__).resolve().parents[1]


def _benchmark():
    spec = importlib.util.spec_from_file_location("impact", REPO / "benchmarks" / "impact.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_default_contact_timeconst_leaves_the_scene_as_built(env):
    scene = sim.load_model()
    assert FPiHConfig().contact_timeconst == 0.02
    np.testing.assert_array_equal(env.mj_model.pair_solref, scene.pair_solref)  # bit for bit
    np.testing.assert_array_equal(np.asarray(env.mjx_model.pair_solref), np.asarray(sim.put_model(scene).pair_solref))
    assert np.all(scene.pair_solref == [0.02, 1.0])


def test_contact_timeconst_reaches_every_peg_pair_of_the_mjx_model():
    env = FPiHEnv(FPiHConfig(contact_timeconst=0.05))
    solref = np.asarray(env.mjx_model.pair_solref)
    assert solref.shape == (env.mj_model.npair, 2) and env.mj_model.npair > 0
    np.testing.assert_array_equal(env.mj_model.pair_solref[:, 0], 0.05)
    np.testing.assert_array_equal(solref[:, 0], np.float32(0.05))  # MJX holds the model in float32
    np.testing.assert_array_equal(solref[:, 1], 1.0)  # damping ratio as built
    peg = set(env.ids.peg_geoms)  # every pair is a peg pair
    assert all({int(a), int(b)} & peg for a, b in zip(env.mj_model.pair_geom1, env.mj_model.pair_geom2))


@pytest.mark.parametrize("value", [0.0, -0.02, math.inf, math.nan, "0.02", None])
def test_bad_contact_timeconst_is_a_one_line_error(value):
    with pytest.raises(ValueError, match="contact_timeconst") as err:
        FPiHConfig(contact_timeconst=value)
    assert "\n" not in str(err.value) and repr(value) in str(err.value)


def test_a_run_config_without_contact_timeconst_loads_with_the_scenes_value():
    data = json.loads(RunSpec().to_json())
    data["env"].pop("contact_timeconst")
    assert RunSpec.from_json(json.dumps(data)).env.contact_timeconst == 0.02
    soft = RunSpec(env=dataclasses.replace(RunSpec().env, contact_timeconst=0.05))
    assert RunSpec.from_json(soft.to_json()).env.contact_timeconst == 0.05


def test_first_contact_window_reads_the_15hz_reading_after_contact():
    """Episode 0 touches at step 2 and reads 12 N five steps later (a hit within the 8-step window);
    episode 1 touches at step 1 and reads 12 N only at step 9 (outside it); episode 2 never touches."""
    T, B = 12, 3
    traj = {k: np.zeros((T, B), np.float32) for k in ("vz", "phase", "in_contact", "wrist", "peak", "lateral")}
    traj["in_contact"][2:, 0] = 1.0
    traj["in_contact"][1:, 1] = 1.0
    traj["vz"][:, 0], traj["vz"][:, 1] = -0.015, -0.004
    traj["wrist"][7, 0], traj["wrist"][9, 1], traj["wrist"][4, 1] = 12.0, 12.0, 3.0
    traj["peak"][2, 0] = 30.0
    traj["lateral"][:, 0] = 0.012
    stats = _benchmark().first_contact(traj, window=8, threshold=10.0)
    assert stats["touched"].tolist() == [True, True, False]
    assert stats["step"].tolist() == [2, 1, T]
    np.testing.assert_allclose(stats["speed_mm_s"][:2], [15.0, 4.0], rtol=1e-6)
    assert stats["hit"].tolist() == [True, False, False]
    np.testing.assert_allclose(stats["reading_peak_n"][:2], [12.0, 3.0])
    assert stats["contact_peak_n"][0] == 30.0 and stats["lateral_mm"][0] == pytest.approx(12.0)
    assert np.isnan(stats["speed_mm_s"][2]) and np.isnan(stats["reading_peak_n"][2])
    assert stats["window_complete"].tolist() == [True, True, False]
