"""ONNX export (`match_jax.transfer.export`): for every method the exported graph, run in onnxruntime, gives the
JAX deterministic policy's action on raw observations through a non-trivial normaliser; the
stochastic output samples with the scaled std; an exported run exports too; bad input is a one-line
error naming the bad value.

The runs are written directly (config.json and a best checkpoint of random weights and normaliser),
without training: the graph must reproduce any weights, and random ones exercise every selection and
the tanh away from zero."""

import match_jax  # noqa: F401

import json

import jax
import jax.numpy as jnp
import numpy as np
import onnx
import pytest

from match_jax.training import checkpoints
from match_jax.transfer import export as ex
from match_jax.rl.distributions import Sample
from match_jax.rl.ppo import deterministic_action
from match_jax.transfer.standin import Policy
from match_jax.training.presets import get_preset
from match_jax.training.runs import Run, RunSpec, export_actors

METHODS = ("pose", "vices", "hybrid", "match")
ATOL = 1e-5


def _random_leaf(rng: np.random.Generator, path, leaf) -> np.ndarray:
    """A random value for one leaf of a policy tree: weights at a scale that keeps the actor's outputs
    O(1) (mixed selections, unsaturated tanh), a normaliser with means O(1) and stds in [0.05, 3]."""
    name, shape, dtype = jax.tree_util.keystr(path), leaf.shape, leaf.dtype
    if not np.issubdtype(dtype, np.floating):
        return np.zeros(shape, dtype)
    if "_stats" in name:
        if name.endswith(".mean"):
            return rng.normal(0.0, 2.0, shape).astype(dtype)
        if name.endswith(".std"):
            return rng.uniform(0.05, 3.0, shape).astype(dtype)
        return np.zeros(shape, dtype)
    if name.endswith("['kernel']"):
        return (1.5 * rng.standard_normal(shape) / np.sqrt(shape[0])).astype(dtype)
    if name.endswith("['scale']"):
        return (1.0 + 0.3 * rng.standard_normal(shape)).astype(dtype)
    if name.endswith("['log_std']"):
        return rng.normal(-1.0, 0.5, shape).astype(dtype)
    return (0.5 * rng.standard_normal(shape)).astype(dtype)


def _write_run(run_dir, method: str, num_seeds: int) -> tuple[Run, list[dict]]:
    """A run directory with config.json and a best checkpoint per seed of random weights."""
    spec = RunSpec(ppo=get_preset("tiny", method=method), num_seeds=num_seeds, preset="tiny")
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(spec.to_json())
    run = Run(spec, run_dir)
    target = run.policy_target()
    policies = []
    for i in range(num_seeds):
        rng = np.random.default_rng(100 * METHODS.index(method) + i)
        policy = jax.tree_util.tree_map_with_path(lambda path, leaf: jnp.asarray(_random_leaf(rng, path, leaf)),
                                                  target)
        checkpoints.save(checkpoints.best_dir(run_dir, i), 1, policy)
        checkpoints.write_best_record(run_dir, i, {"iteration": 1, "env_steps": 32, "success_rate": 0.5,
                                                   "break_rate": 0.0})
        policies.append(policy)
    return run, policies


class _Runs(dict):
    """method -> (run directory, Run, random policy per seed), written on first use; MATCH has two seeds."""

    def __init__(self, root):
        super().__init__()
        self.root = root

    def __missing__(self, method: str):
        run, policies = _write_run(self.root / method, method, 2 if method == "match" else 1)
        self[method] = (self.root / method, run, policies)
        return self[method]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return _Runs(tmp_path_factory.mktemp("export_runs"))


def _raw_observations(policy: dict, count: int = 64, seed: int = 7) -> np.ndarray:
    """Raw observations around the normaliser's mean, +-4 std, a few rows far past the +-10 clip."""
    stats = policy["policy_stats"]
    mean, std = np.asarray(stats.mean), np.asarray(stats.std)
    z = np.random.default_rng(seed).normal(0.0, 4.0, (count, mean.size))
    z[:4] *= 5.0
    return (mean + std * z).astype(np.float32)


def _reference(run: Run, policy: dict, obs: np.ndarray) -> np.ndarray:
    fn = jax.jit(lambda params, stats, o: deterministic_action(run.trainer, params, stats, o))
    return np.asarray(fn(policy["params"], policy["policy_stats"], obs))


def _run_onnx(path, feeds: dict) -> dict:
    sess = ex.session(path)
    return dict(zip([o.name for o in sess.get_outputs()], sess.run(None, feeds)))


@pytest.mark.parametrize("method", METHODS)
def test_onnx_action_equals_the_jax_deterministic_action(runs, method, tmp_path):
    run_dir, run, policies = runs[method]
    result = ex.export_policy(run_dir, tmp_path)
    assert result.onnx_path == tmp_path / "policy_seed0.onnx" and result.max_abs_error <= ATOL
    obs = _raw_observations(policies[0])
    got = _run_onnx(result.onnx_path, {"obs": obs})
    want = _reference(run, policies[0], obs)
    assert got["action"].shape == want.shape == (64, run.trainer.distribution.space.size)
    np.testing.assert_allclose(got["action"], want, rtol=0, atol=ATOL)
    space = run.trainer.distribution.space
    assert np.ptp(want[:, list(space.continuous)], axis=0).min() > 0.2  # the outputs vary: a real check
    if space.selection:
        selections = want[:, list(space.selection)]
        assert 0.05 < selections.mean() < 0.95  # both modes occur
        head = run.trainer.policy_head(policies[0]["params"], policies[0]["policy_stats"], obs)
        np.testing.assert_allclose(got["p_force"], np.asarray(jax.nn.sigmoid(head.logits)), rtol=0, atol=ATOL)
    else:
        assert set(got) == {"action"}

    description = json.loads(result.json_path.read_text())
    layout = description["observation"]["components"]
    assert [c["name"] for c in layout] == list(run.env.policy_obs_layout)
    assert [c["start"] for c in layout] == [s.start for s in run.env.policy_obs_layout.values()]
    assert sum(c["size"] for c in layout) == description["observation"]["size"] == obs.shape[1]
    assert all(c["units"] and c["frame"] for c in layout)
    assert description["method"] == method and description["policy_rate_hz"] == pytest.approx(15.0)
    assert [c["name"] for c in description["action"]["components"]] == space.describe()
    assert [(c["low"], c["high"]) for c in description["action"]["components"]] == list(zip(space.low, space.high))
    sess = ex.session(result.onnx_path)
    assert [i["name"] for i in description["onnx"]["inputs"]] == [i.name for i in sess.get_inputs()] == ["obs"]
    assert [o["name"] for o in description["onnx"]["outputs"]] == [o.name for o in sess.get_outputs()]
    assert description["run_config"]["method"] == method and description["source"]["checkpoint"] == "best"
    model = onnx.load(result.onnx_path)
    assert json.loads({p.key: p.value for p in model.metadata_props}[ex.METADATA_KEY]) == description


def test_stochastic_output_samples_with_the_scaled_std(runs, tmp_path):
    run_dir, run, policies = runs["hybrid"]
    assert ex.main([str(run_dir), str(tmp_path), "--stochastic", "--std-scale", "0.05"]) == 0
    policy, obs = policies[0], _raw_observations(policies[0])
    noise = np.random.default_rng(3).standard_normal((obs.shape[0], 7)).astype(np.float32)
    got = _run_onnx(tmp_path / "policy_seed0.onnx", {"obs": obs, "noise": noise})
    head = run.trainer.policy_head(policy["params"], policy["policy_stats"], obs)
    dist = run.trainer.distribution
    want = dist.to_action(Sample(head.mean + 0.05 * jnp.exp(head.log_std) * noise, (head.logits > 0).astype(jnp.float32)))
    np.testing.assert_allclose(got["sampled_action"], np.asarray(want), rtol=0, atol=ATOL)
    np.testing.assert_allclose(got["action"], _reference(run, policy, obs), rtol=0, atol=ATOL)
    assert np.abs(got["sampled_action"] - got["action"]).max() > 1e-3  # the noise acts
    description = json.loads((tmp_path / "policy_seed0.json").read_text())
    assert description["stochastic"]["std_scale"] == 0.05
    assert [i["name"] for i in description["onnx"]["inputs"]] == ["obs", "noise"]


def test_the_standin_samples_the_stochastic_export_reproducibly(runs, tmp_path):
    """The stand-in's policy runs the ONNX file: the deterministic action by default; with a noise seed the
    sampled action with that seed's standard-normal noise, the same for the same seed; an export without
    the stochastic output cannot be sampled."""
    run_dir, _, policies = runs["hybrid"]
    assert ex.main([str(run_dir), str(tmp_path / "sto"), "--stochastic", "--std-scale", "0.05"]) == 0
    assert ex.main([str(run_dir), str(tmp_path / "det")]) == 0
    path, obs = tmp_path / "sto" / "policy_seed0.onnx", _raw_observations(policies[0], count=5)
    first, again, other = (Policy(path, noise_seed=s) for s in ((4, 1), (4, 1), (5, 1)))
    noise = np.random.default_rng((4, 1)).standard_normal((5, 7)).astype(np.float32)
    want = _run_onnx(path, {"obs": obs, "noise": noise})
    got = np.stack([first(o) for o in obs])
    np.testing.assert_allclose(got, want["sampled_action"], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(got, np.stack([again(o) for o in obs]))
    assert np.abs(got - np.stack([other(o) for o in obs])).max() > 1e-4
    np.testing.assert_allclose(np.stack([Policy(path)(o) for o in obs]), want["action"], rtol=0, atol=1e-6)
    assert first.deployment == "stochastic, std x 0.05" and Policy(path).deployment == "deterministic"
    with pytest.raises(ValueError, match="--stochastic"):
        Policy(tmp_path / "det" / "policy_seed0.onnx", noise_seed=0)


def test_an_exported_run_exports_its_seeds(runs, tmp_path):
    run_dir, run, policies = runs["match"]
    shipped = export_actors(run_dir, tmp_path / "shipped")
    result = ex.export_policy(shipped, tmp_path / "onnx", seed_index=1)
    obs = _raw_observations(policies[1])
    got = _run_onnx(result.onnx_path, {"obs": obs})["action"]
    np.testing.assert_allclose(got, _reference(run, policies[1], obs), rtol=0, atol=ATOL)
    assert np.abs(got - _reference(run, policies[0], obs)).max() > 0.1  # seed 1, not seed 0
    assert json.loads(result.json_path.read_text())["source"]["seed_index"] == 1


def test_bad_run_dir_seed_index_or_flag_is_a_one_line_error(runs, tmp_path, capsys):
    run_dir = runs["match"][0]

    def error_of(argv) -> str:
        assert ex.main(argv) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1, lines
        return lines[0]

    assert str(tmp_path / "no_such_run") in error_of([str(tmp_path / "no_such_run"), str(tmp_path / "out")])
    assert "seed index 2 out of range" in error_of([str(run_dir), str(tmp_path / "out"), "--seed-index", "2"])
    assert "seed index -1" in error_of([str(run_dir), str(tmp_path / "out"), "--seed-index", "-1"])
    (tmp_path / "file").write_text("")
    assert "is a file" in error_of([str(run_dir), str(tmp_path / "file")])
    assert not (tmp_path / "out").exists()
    with pytest.raises(SystemExit) as exit_info:
        ex.main([str(run_dir), str(tmp_path / "out"), "--std-scale", "0.05"])
    assert exit_info.value.code == 2 and "--std-scale needs --stochastic" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ex.main([str(run_dir), str(tmp_path / "out"), "--stochastic", "--std-scale", "0"])
    assert "--std-scale must be a finite number > 0, got 0.0" in capsys.readouterr().err
