"""Policy export to ONNX: one seed's actor as a graph from the raw policy observation to the env action.

    python -m match_jax.transfer.export RUN_DIR OUT_DIR [--seed-index I] [--checkpoint best|latest]
                               [--stochastic --std-scale 0.05]

writes OUT_DIR/policy_seed<I>.onnx and, beside it, OUT_DIR/policy_seed<I>.json (docs/export.md). The
graph holds the observation normaliser (clip((obs - mean) / std, +-10)), the SimBa actor and the
deterministic action mapping of `ppo.deterministic_action`: tanh of the mean on the continuous
components (the env's action bounds are [-1, 1]) and, for Hybrid-Basic and MATCH, force control on a
world axis where p_force > 0.5. With `stochastic` the graph also takes standard-normal `noise` and
outputs `sampled_action`, tanh(mean + std_scale * std * noise), with the same deterministic selections.

The graph is written with the `onnx` package's helper API from the actor's weights (jax2onnx converts
the function too, but its releases 0.14-0.17 pin orbax-checkpoint < 0.11.37, below the
orbax-checkpoint this package checkpoints with). Before writing, the export runs the graph in
onnxruntime on random observations and compares it with the JAX deterministic policy.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import pathlib
import sys

import numpy as np

OPSET = 17
OBS_CLIP = 10.0  # the normaliser's clip (`ppo.normalize`)
INPUT_OBS, INPUT_NOISE = "obs", "noise"
OUTPUT_ACTION, OUTPUT_SAMPLED, OUTPUT_P_FORCE = "action", "sampled_action", "p_force"
VERIFY_OBSERVATIONS = 64
VERIFY_ATOL = 1e-5
FORMAT = "match_jax.transfer.export/1"
METADATA_KEY = "match_jax"  # the ONNX metadata entry holding the JSON description


class ExportError(ValueError):
    """A run that cannot be exported, or an export that does not reproduce the JAX policy (one line)."""


@dataclasses.dataclass(frozen=True, eq=False)
class Dense:
    """y = x @ kernel + bias; kernel (in, out), float32."""

    kernel: np.ndarray
    bias: np.ndarray


@dataclasses.dataclass(frozen=True, eq=False)
class LayerNorm:
    """Flax's LayerNorm over the last axis: (x - E[x]) * rsqrt(E[x^2] - E[x]^2 + epsilon) * scale + bias."""

    scale: np.ndarray
    bias: np.ndarray
    epsilon: float


@dataclasses.dataclass(frozen=True, eq=False)
class Block:
    """A SimBa residual block: x + out(relu(hidden(norm(x))))."""

    norm: LayerNorm
    hidden: Dense
    out: Dense


@dataclasses.dataclass(frozen=True, eq=False)
class ActorWeights:
    """The weights of a `networks.Actor`: SimBa trunk, mean head, optional selection head, log std.

    log_std is the clipped pre-tanh log std (`NetworkConfig.min_log_std`..`max_log_std`), one per
    continuous component."""

    embed: Dense
    blocks: tuple[Block, ...]
    final_norm: LayerNorm
    mean: Dense
    selection: Dense | None
    log_std: np.ndarray


@dataclasses.dataclass(frozen=True, eq=False)
class Normaliser:
    """The policy observation normaliser: clip((obs - mean) / std, -clip, clip), obs in raw env units."""

    mean: np.ndarray
    std: np.ndarray
    clip: float = OBS_CLIP


@dataclasses.dataclass(frozen=True)
class ActionMapping:
    """Where the actor's outputs go in the env's action vector (`ActionSpace`).

    continuous[k]: the action index of the k-th mean; selection[j]: the action index of world axis j's
    selection (empty for pose and VICES). std_scale: the factor on the policy std of `sampled_action`
    (None: no stochastic output)."""

    size: int
    continuous: tuple[int, ...]
    selection: tuple[int, ...]
    std_scale: float | None = None


@dataclasses.dataclass(frozen=True)
class ExportResult:
    """The written files and the largest |ONNX - JAX| action difference over the check's observations."""

    onnx_path: pathlib.Path
    json_path: pathlib.Path
    max_abs_error: float


def _f32(x) -> np.ndarray:
    return np.asarray(x, np.float32)


def actor_weights(actor_params: dict, network) -> ActorWeights:
    """The weights of a Flax `Actor`'s variables ({'params': ...}) under `network` (a NetworkConfig)."""
    import flax.linen as nn

    epsilon = float(nn.LayerNorm().epsilon)
    try:
        p = actor_params["params"]
        trunk = p["SimBaTrunk_0"]
        blocks = sum(1 for name in trunk if name.startswith("LayerNorm_")) - 1

        def dense(tree) -> Dense:
            return Dense(_f32(tree["kernel"]), _f32(tree["bias"]))

        def norm(tree) -> LayerNorm:
            return LayerNorm(_f32(tree["scale"]), _f32(tree["bias"]), epsilon)

        weights = ActorWeights(
            embed=dense(trunk["Dense_0"]),
            blocks=tuple(Block(norm(trunk[f"LayerNorm_{i}"]), dense(trunk[f"Dense_{2 * i + 1}"]),
                               dense(trunk[f"Dense_{2 * i + 2}"])) for i in range(blocks)),
            final_norm=norm(trunk[f"LayerNorm_{blocks}"]),
            mean=dense(p["Dense_0"]),
            selection=dense(p["Dense_1"]) if "Dense_1" in p else None,
            log_std=np.clip(_f32(p["log_std"]), network.min_log_std, network.max_log_std).astype(np.float32),
        )
    except (KeyError, TypeError) as err:
        raise ExportError(f"the actor's parameters are not a SimBa Actor's (missing {err})") from None
    if blocks != network.actor_blocks or weights.embed.kernel.shape[1] != network.actor_hidden:
        raise ExportError(f"the actor has {blocks} blocks of width {weights.embed.kernel.shape[1]}; the run config "
                          f"gives {network.actor_blocks} of width {network.actor_hidden}")
    return weights


class _Graph:
    """Nodes and initializers of an ONNX graph under construction, with fresh value names."""

    def __init__(self):
        self.nodes, self.initializers, self._count = [], [], 0

    def name(self, hint: str) -> str:
        self._count += 1
        return f"{hint}_{self._count}"

    def const(self, value, hint: str) -> str:
        from onnx import numpy_helper

        name = self.name(hint)
        self.initializers.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    def op(self, op_type: str, *inputs: str, hint: str | None = None, output: str | None = None, **attrs) -> str:
        from onnx import helper

        output = output or self.name(hint or op_type.lower())
        self.nodes.append(helper.make_node(op_type, list(inputs), [output], **attrs))
        return output

    def dense(self, x: str, layer: Dense, hint: str) -> str:
        y = self.op("MatMul", x, self.const(layer.kernel, f"{hint}_kernel"), hint=hint)
        return self.op("Add", y, self.const(layer.bias, f"{hint}_bias"), hint=hint)

    def layer_norm(self, x: str, layer: LayerNorm, hint: str) -> str:
        mean = self.op("ReduceMean", x, axes=[-1], keepdims=1, hint=f"{hint}_mean")
        mean_sq = self.op("ReduceMean", self.op("Mul", x, x), axes=[-1], keepdims=1, hint=f"{hint}_mean_sq")
        var = self.op("Max", self.op("Sub", mean_sq, self.op("Mul", mean, mean)), self.const(_f32(0.0), "zero"),
                      hint=f"{hint}_var")
        rsqrt = self.op("Reciprocal", self.op("Sqrt", self.op("Add", var, self.const(_f32(layer.epsilon), "eps"))))
        mul = self.op("Mul", rsqrt, self.const(layer.scale, f"{hint}_scale"))
        y = self.op("Mul", self.op("Sub", x, mean), mul)
        return self.op("Add", y, self.const(layer.bias, f"{hint}_bias"), hint=hint)


def _assemble(g: _Graph, continuous: str, selection: str | None, mapping: ActionMapping, output: str) -> str:
    """The action vector from the continuous components and the selections, in `mapping`'s order."""
    parts, order = [continuous], list(mapping.continuous)
    if selection is not None:
        parts, order = [selection, continuous], list(mapping.selection) + list(mapping.continuous)
    position = np.argsort(np.asarray(order)).astype(np.int64)  # action index -> column of the concatenation
    joined = g.op("Concat", *parts, axis=-1) if len(parts) > 1 else parts[0]
    if np.array_equal(position, np.arange(mapping.size)):
        return g.op("Identity", joined, output=output)
    return g.op("Gather", joined, g.const(position, "action_order"), axis=-1, output=output)


def policy_model(weights: ActorWeights, normaliser: Normaliser, mapping: ActionMapping, doc: str = ""):
    """The ONNX model (onnx.ModelProto) of the policy: input `obs` (batch, obs size) raw float32; output
    `action` (batch, action size); with selections also `p_force` (batch, 3); with mapping.std_scale
    also input `noise` (batch, continuous components) and output `sampled_action`."""
    import onnx
    from onnx import TensorProto, helper

    obs_size, n_cont = weights.embed.kernel.shape[0], weights.mean.kernel.shape[1]
    if len(mapping.continuous) != n_cont or len(mapping.selection) != (0 if weights.selection is None
                                                                        else weights.selection.kernel.shape[1]):
        raise ExportError(f"the actor's heads ({n_cont} means, selections: {weights.selection is not None}) do not "
                          f"match the action space (continuous {mapping.continuous}, selection {mapping.selection})")
    g = _Graph()
    x = g.op("Div", g.op("Sub", INPUT_OBS, g.const(normaliser.mean, "obs_mean")), g.const(normaliser.std, "obs_std"))
    x = g.op("Clip", x, g.const(_f32(-normaliser.clip), "clip_low"), g.const(_f32(normaliser.clip), "clip_high"),
             hint="normalised_obs")
    x = g.dense(x, weights.embed, "embed")
    for i, block in enumerate(weights.blocks):
        y = g.layer_norm(x, block.norm, f"block{i}_norm")
        y = g.op("Relu", g.dense(y, block.hidden, f"block{i}_hidden"))
        x = g.op("Add", x, g.dense(y, block.out, f"block{i}_out"), hint=f"block{i}")
    x = g.layer_norm(x, weights.final_norm, "final_norm")
    mean = g.dense(x, weights.mean, "mean")
    selection = None
    outputs = [helper.make_tensor_value_info(OUTPUT_ACTION, TensorProto.FLOAT, ["batch", mapping.size])]
    if weights.selection is not None:
        logits = g.dense(x, weights.selection, "selection_logits")
        g.op("Sigmoid", logits, output=OUTPUT_P_FORCE)
        selection = g.op("Cast", g.op("Greater", logits, g.const(_f32(0.0), "zero")), to=TensorProto.FLOAT,
                         hint="selection")
        outputs.append(helper.make_tensor_value_info(OUTPUT_P_FORCE, TensorProto.FLOAT,
                                                     ["batch", len(mapping.selection)]))
    _assemble(g, g.op("Tanh", mean), selection, mapping, OUTPUT_ACTION)
    inputs = [helper.make_tensor_value_info(INPUT_OBS, TensorProto.FLOAT, ["batch", obs_size])]
    if mapping.std_scale is not None:
        std = _f32(np.exp(weights.log_std) * np.float32(mapping.std_scale))
        pre_tanh = g.op("Add", mean, g.op("Mul", INPUT_NOISE, g.const(std, "sample_std")))
        _assemble(g, g.op("Tanh", pre_tanh), selection, mapping, OUTPUT_SAMPLED)
        inputs.append(helper.make_tensor_value_info(INPUT_NOISE, TensorProto.FLOAT, ["batch", n_cont]))
        outputs.append(helper.make_tensor_value_info(OUTPUT_SAMPLED, TensorProto.FLOAT, ["batch", mapping.size]))
    graph = helper.make_graph(g.nodes, "match_jax_policy", inputs, outputs, g.initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="match_jax.transfer.export",
                              doc_string=doc)
    model.ir_version = helper.find_min_ir_version_for(model.opset_import)  # readable by older runtimes too
    onnx.checker.check_model(model)
    return model


def action_mapping(space, std_scale: float | None = None) -> ActionMapping:
    """The ActionMapping of an `ActionSpace`."""
    return ActionMapping(space.size, tuple(space.continuous), tuple(space.selection), std_scale)


def observation_layout(env) -> list[dict]:
    """The policy observation obs['state'] of an FPiHEnv, component by component, in order."""
    cfg = env.config
    if cfg.force_frame == "world":
        wrench_frame = "world"
    else:
        wrench_frame = "hand, the authors' reading -R_hand^T v (hand pointing down at yaw 0: (-x, y, z) of world)"
    sensor = ("wrist force/torque sensor, tared for the hand + peg weight" if cfg.force_sensor == "wrist"
              else "sum of the peg's contact forces")
    described = {
        "ee_rel_hole": ("m", "world", "end-effector (fingertip site 'ee') position minus the observed hole top "
                        "(true hole top + the episode's hole-position observation error)"),
        "hole_yaw_cos_sin": ("1", "world z", "cos and sin of the hole block's yaw about world z"),
        "ee_lin_vel": ("m/s", "world", "linear velocity of the end-effector site"),
        "ee_ang_vel": ("rad/s", "world", "angular velocity of the hand"),
        "ee_force": ("N", wrench_frame,
                     f"force the robot applies to the environment (pressing down: F_z < 0), {sensor}"),
        "ee_torque": ("N m", wrench_frame,
                      f"torque the robot applies to the environment about the wrist site, {sensor}"),
        "prev_action": ("action units", "action layout",
                        "the previous step's applied action, after the EMA smoothing (selections unsmoothed); "
                        "the neutral action ('action.neutral') at the episode start"),
    }
    layout = []
    for name, part in env.policy_obs_layout.items():
        units, frame, description = described.get(name, ("", "", "see match_jax/envs/fpih.py"))
        layout.append({"name": name, "start": part.start, "size": part.stop - part.start, "units": units,
                       "frame": frame, "description": description})
    return layout


def action_layout(space, actions) -> list[dict]:
    """The env action vector of an `ActionSpace` under an `ActionConfig`, component by component."""
    fz_lo, fz_hi = actions.force_z_range
    k_lo, k_hi = actions.stiffness_range
    meaning = {
        "pos": f"position target = current end-effector position + a * {actions.pos_scale} m (world frame), "
               f"clipped to +-{actions.pos_box} m around the observed hole top",
        "yaw": f"yaw target = current yaw + a * {actions.yaw_scale} rad about world z; "
               "roll and pitch held pointing down",
        "select_force": f"1 = force control on this world axis (the env applies force where > "
                        f"{actions.selection_threshold}), 0 = position control",
        "force_xy": f"force target = a * {actions.force_xy_max} N (world frame, robot on environment)",
        "force_z": f"force target = lo + (a + 1) / 2 * (hi - lo), [lo, hi] = [{fz_lo}, {fz_hi}] N (world frame, "
                   "robot on environment; < 0 presses down)",
        "stiffness": f"translational stiffness = lo + (a + 1) / 2 * (hi - lo), [lo, hi] = [{k_lo}, {k_hi}] N/m",
    }
    components = []
    for index, name in enumerate(space.describe()):
        group = name.rsplit("_", 1)[0]
        key = ("force_z" if name == "force_z" else "force_xy") if group == "force" else group
        components.append({"index": index, "name": name, "low": float(space.low[index]),
                           "high": float(space.high[index]), "meaning": meaning[key]})
    return components


def env_description(env) -> dict:
    """What a policy of `env` (an FPiHEnv) reads and writes: 'control', 'policy_rate_hz', 'observation'
    (size, components) and 'action' (layout, bounds, neutral action, smoothing, scaling config)."""
    space = env.action_space
    obs_layout = observation_layout(env)
    return {
        "control": env.config.control,
        "policy_rate_hz": 1.0 / env.config.policy_dt,
        "observation": {"size": sum(part["size"] for part in obs_layout), "components": obs_layout},
        "action": {"size": space.size, "components": action_layout(space, env.config.actions),
                   "continuous_indices": list(space.continuous), "selection_indices": list(space.selection),
                   "neutral": np.asarray(env.neutral_action(), np.float64).tolist(), "ema": env.config.actions.ema,
                   "smoothing": "the env applies a_ema = ema * a + (1 - ema) * a_prev to the continuous components "
                                "(selections unsmoothed) and observes a_ema as the next prev_action",
                   "config": dataclasses.asdict(env.config.actions)},
    }


def run_summary(spec) -> dict:
    """The parts of a RunSpec that say what the policy was trained for."""
    ppo, env = spec.ppo, spec.env
    net = ppo.network
    return {
        "preset": spec.preset, "num_seeds": spec.num_seeds, "seed": spec.seed, "method": ppo.method,
        "total_steps": ppo.total_steps, "ssl_beta": ppo.ssl_beta, "selection_in_ratio": ppo.selection_in_ratio,
        "network": {"actor_hidden": net.actor_hidden, "actor_blocks": net.actor_blocks},
        "env": {name: getattr(env, name) for name in (
            "control", "force_sensor", "force_frame", "observe_torque", "break_force", "break_sampling",
            "episode_steps", "control_substeps", "control_dt", "hole_obs_noise", "hole_obs_noise_type")},
    }


def _io(mapping: ActionMapping, obs_size: int) -> dict:
    inputs = [{"name": INPUT_OBS, "shape": ["batch", obs_size], "dtype": "float32",
               "description": "raw (unnormalised) policy observation, laid out as 'observation'"}]
    outputs = [{"name": OUTPUT_ACTION, "shape": ["batch", mapping.size], "dtype": "float32",
                "description": "deterministic action: tanh(mean); selections 1 where p_force > 0.5"}]
    if mapping.selection:
        outputs.append({"name": OUTPUT_P_FORCE, "shape": ["batch", len(mapping.selection)], "dtype": "float32",
                        "description": "probability of force control per world axis (x, y, z)"})
    if mapping.std_scale is not None:
        inputs.append({"name": INPUT_NOISE, "shape": ["batch", len(mapping.continuous)], "dtype": "float32",
                       "description": "standard-normal noise, one per continuous component (action indices "
                                      f"{list(mapping.continuous)})"})
        outputs.append({"name": OUTPUT_SAMPLED, "shape": ["batch", mapping.size], "dtype": "float32",
                        "description": f"tanh(mean + {mapping.std_scale} * std * noise); selections as in 'action'"})
    return {"opset": OPSET, "inputs": inputs, "outputs": outputs}


def jax_actions(trainer, policy: dict, obs, noise=None, std_scale: float | None = None):
    """The JAX policy's deterministic action (`ppo.deterministic_action`) of raw observations `obs`
    (batch, obs size) and, with `noise`, the action sampled with the std scaled by `std_scale`."""
    import jax
    import jax.numpy as jnp

    from match_jax.rl.distributions import Sample

    dist = trainer.distribution

    @jax.jit
    def actions(params, stats, obs, noise):
        head = trainer.policy_head(params, stats, obs)
        mode = dist.mode(head)
        sampled = None
        if noise is not None:
            sampled = dist.to_action(Sample(head.mean + std_scale * jnp.exp(head.log_std) * noise, mode.selection))
        return dist.to_action(mode), sampled

    action, sampled = actions(policy["params"], policy["policy_stats"], jnp.asarray(obs, jnp.float32),
                              None if noise is None else jnp.asarray(noise, jnp.float32))
    return np.asarray(action), None if sampled is None else np.asarray(sampled)


def session(model_or_path):
    """An onnxruntime CPU session of a model (onnx.ModelProto, bytes or a path), one thread."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads, options.inter_op_num_threads = 1, 1
    source = model_or_path.SerializeToString() if hasattr(model_or_path, "SerializeToString") else str(model_or_path)
    return ort.InferenceSession(source, options, providers=["CPUExecutionProvider"])


def check_observations(normaliser: Normaliser, count: int = VERIFY_OBSERVATIONS, seed: int = 0) -> np.ndarray:
    """(count, obs size) raw observations spread over the normaliser's range: mean + 3 std N(0, 1), the
    last eighth at +-15 std (beyond the +-10 clip)."""
    rng = np.random.default_rng(seed)
    z = 3.0 * rng.standard_normal((count, normaliser.mean.size))
    z[-max(1, count // 8):] = 15.0 * np.sign(z[-max(1, count // 8):])
    return _f32(normaliser.mean + normaliser.std * z)


def verify(model, trainer, policy: dict, mapping: ActionMapping, normaliser: Normaliser) -> float:
    """The largest |ONNX - JAX| action difference (deterministic and, if present, sampled) on
    `check_observations`; ExportError above VERIFY_ATOL."""
    obs = check_observations(normaliser)
    feeds = {INPUT_OBS: obs}
    noise = None
    if mapping.std_scale is not None:
        noise = _f32(np.random.default_rng(1).standard_normal((obs.shape[0], len(mapping.continuous))))
        feeds[INPUT_NOISE] = noise
    got = dict(zip([o.name for o in model.graph.output], session(model).run(None, feeds)))
    action, sampled = jax_actions(trainer, policy, obs, noise, mapping.std_scale)
    error = float(np.max(np.abs(got[OUTPUT_ACTION] - action)))
    if sampled is not None:
        error = max(error, float(np.max(np.abs(got[OUTPUT_SAMPLED] - sampled))))
    if not error <= VERIFY_ATOL:
        raise ExportError(f"the ONNX graph differs from the JAX policy by {error:.3g} (> {VERIFY_ATOL}) on "
                          f"{obs.shape[0]} check observations")
    return error


def onnx_path(out_dir: pathlib.Path, seed_index: int) -> pathlib.Path:
    """Where `export_policy` writes seed `seed_index`'s ONNX file."""
    return pathlib.Path(out_dir) / f"policy_seed{seed_index}.onnx"


def export_policy(run_dir: str | pathlib.Path, out_dir: str | pathlib.Path, seed_index: int = 0,
                  checkpoint: str = "best", std_scale: float | None = None) -> ExportResult:
    """Export seed `seed_index`'s policy ('best' or 'latest' checkpoint; exported runs: 'best') of a run
    directory to OUT_DIR/policy_seed<i>.onnx + .json; std_scale (> 0): add the stochastic output."""
    from match_jax.training.runs import best_record, is_exported, load_policy

    if std_scale is not None and not (isinstance(std_scale, (int, float)) and 0 < std_scale < math.inf):
        raise ExportError(f"std scale must be a finite number > 0, got {std_scale!r}")
    out_dir = pathlib.Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ExportError(f"{out_dir} is a file, not an output directory")
    run, policy = load_policy(run_dir, seed_index, checkpoint)
    spec, env = run.spec, run.env
    space = run.trainer.distribution.space
    mapping = action_mapping(space, std_scale)
    weights = actor_weights(policy["params"]["actor"], spec.ppo.network)
    stats = policy["policy_stats"]
    normaliser = Normaliser(_f32(stats.mean), _f32(stats.std))
    obs_layout = observation_layout(env)
    obs_size = sum(part["size"] for part in obs_layout)
    if obs_size != normaliser.mean.size:
        raise ExportError(f"the observation layout has {obs_size} values, the normaliser {normaliser.mean.size}")
    path = onnx_path(out_dir, seed_index)
    record = best_record(run.dir, seed_index) if checkpoint == "best" else None
    description = {
        "format": FORMAT,
        "onnx_file": path.name,
        "method": spec.ppo.method,
        "onnx": _io(mapping, obs_size),
        **env_description(env),
        "normaliser": {"formula": f"clip((obs - mean) / std, -{OBS_CLIP}, {OBS_CLIP})",
                       "mean": normaliser.mean.tolist(), "std": normaliser.std.tolist()},
        "deterministic": "tanh(mean) on the continuous components; selection 1 (force) where p_force > 0.5",
        "stochastic": None if std_scale is None else {
            "std_scale": std_scale, "std": (np.exp(weights.log_std) * std_scale).tolist(),
            "formula": "tanh(mean + std_scale * exp(log_std) * noise), noise ~ N(0, 1); selections deterministic"},
        "source": {"run_dir": str(run.dir), "exported_run": is_exported(run.dir), "seed_index": seed_index,
                   "seed": spec.seed + seed_index, "checkpoint": checkpoint, "record": record},
        "run_config": run_summary(spec),
    }
    model = policy_model(weights, normaliser, mapping,
                         doc=f"match_jax {spec.ppo.method} policy, seed index {seed_index} of {run.dir}")
    error = verify(model, run.trainer, policy, mapping, normaliser)
    description["verification"] = {"observations": VERIFY_OBSERVATIONS, "max_abs_error": error,
                                   "atol": VERIFY_ATOL, "against": "match_jax.rl.ppo.deterministic_action"}
    model.metadata_props.add(key=METADATA_KEY, value=json.dumps(description, allow_nan=True))
    out_dir.mkdir(parents=True, exist_ok=True)
    path.write_bytes(model.SerializeToString())
    json_path = path.with_suffix(".json")
    json_path.write_text(json.dumps(description, indent=2, allow_nan=True) + "\n")
    return ExportResult(path, json_path, error)


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m match_jax.transfer.export", description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=pathlib.Path, metavar="RUN_DIR", help="a training run (or an exported run)")
    parser.add_argument("out_dir", type=pathlib.Path, metavar="OUT_DIR", help="where to write the .onnx and .json")
    parser.add_argument("--seed-index", type=int, default=0, help="which seed of the run (default 0)")
    parser.add_argument("--checkpoint", choices=("best", "latest"), default="best")
    parser.add_argument("--stochastic", action="store_true",
                        help="add input 'noise' and output 'sampled_action' (std scaled by --std-scale)")
    parser.add_argument("--std-scale", type=float, default=None,
                        help="factor on the policy std of the sampled action (default 0.05; needs --stochastic)")
    args = parser.parse_args(argv)
    if args.std_scale is not None and not args.stochastic:
        parser.error("--std-scale needs --stochastic")
    if args.stochastic and args.std_scale is None:
        args.std_scale = 0.05
    if args.stochastic and not 0 < args.std_scale < math.inf:
        parser.error(f"--std-scale must be a finite number > 0, got {args.std_scale}")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    from match_jax import compile_cache
    from match_jax.training.checkpoints import CheckpointError
    from match_jax.training.runs import RunError

    compile_cache.enable()
    try:
        result = export_policy(args.run_dir, args.out_dir, args.seed_index, args.checkpoint,
                               args.std_scale if args.stochastic else None)
    except (RunError, CheckpointError, ExportError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {result.onnx_path} and {result.json_path.name} (max |ONNX - JAX| {result.max_abs_error:.2g})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
