"""The host side of training: run directory, jitted chunks, logging, checkpoints, resume.

    from match_jax.training.runs import RunSpec, train
    from match_jax.training.presets import get_preset
    summary = train(RunSpec(ppo=get_preset("cpu", method="match"), num_seeds=1), "runs/match")

A run directory holds `config.json` (the resolved RunSpec), `metrics.jsonl` (one row per iteration
and seed), `metrics.csv` (the same, written at the end of each chunk) and `checkpoints/` (see
`match_jax.training.checkpoints`). Between jitted chunks of `iterations_per_chunk` PPO iterations the host
logs, updates the progress bar and saves checkpoints. Ctrl-C or SIGTERM stops a run after the running
chunk, saved as any chunk is; a run killed otherwise resumes from its latest checkpoint and loses at
most one chunk of work. Checkpoints are written from a host copy of the state
on a background thread while the next chunk runs (at the paper preset with 5 seeds a chunk's
checkpoints are ~2 GB); the next save, the end of the run and an interruption wait for that write.
"""

from __future__ import annotations

import concurrent.futures
import csv
import dataclasses
import functools
import json
import math
import os
import pathlib
import signal
import sys
import threading
import time

import flax.serialization
import jax
import numpy as np

from match_jax.training import checkpoints
from match_jax.cli import unwritable
from match_jax.envs.controllers.action_spaces import ActionConfig
from match_jax.envs.controllers.osc import ControllerConfig
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.rl.networks import NetworkConfig
from match_jax.envs.randomization import ModelRandomization
from match_jax.rl.ppo import SSL_BETA, PPOConfig, RuntimeValues, Trainer, TrainState, make_trainer

LOGGED = ("iteration", "env_steps", "success_rate", "break_rate", "episodes", "mean_reward", "contact_fraction",
          "loss", "policy_loss", "value_loss", "ssl_loss", "entropy", "approx_kl", "clip_fraction", "p_force",
          "action_std", "p_force_contact", "p_force_free", "p_force_contact_axis", "p_force_free_axis", "learning_rate",
          "actor_steps")


class RunError(ValueError):
    """Bad run directory or resume request (one-line message)."""


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything that defines a run: the learner, the task, how many seeds and the base seed."""

    ppo: PPOConfig = PPOConfig()
    env: FPiHConfig | None = None  # None: default_env_config(ppo) (the paper's task)
    num_seeds: int = 1
    seed: int = 0
    preset: str = ""

    def __post_init__(self):
        if not (isinstance(self.num_seeds, int) and self.num_seeds >= 1):
            raise ValueError(f"num_seeds must be an integer >= 1, got {self.num_seeds!r}")
        if self.env is None:
            object.__setattr__(self, "env", default_env_config(self.ppo))
        if self.env.control != self.ppo.control:
            raise ValueError(f"method {self.ppo.method!r} needs env control {self.ppo.control!r}, "
                             f"got {self.env.control!r}")

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, allow_nan=True)

    @classmethod
    def from_json(cls, text: str) -> "RunSpec":
        return _from_dict(cls, json.loads(text))


_NESTED = {"ppo": PPOConfig, "env": FPiHConfig, "network": NetworkConfig, "controller": ControllerConfig,
           "actions": ActionConfig, "randomization": ModelRandomization}


def _from_dict(cls, data: dict):
    kwargs = {}
    names = {f.name for f in dataclasses.fields(cls)}
    # a config recorded before a field existed ran that field's legacy value, not today's default
    data = {**getattr(cls, "LEGACY_DEFAULTS", {}), **data}
    for key, value in data.items():
        if key not in names:
            continue  # a field of an older version: ignore
        if key in _NESTED and isinstance(value, dict):
            value = _from_dict(_NESTED[key], value)
        elif isinstance(value, list):
            value = tuple(tuple(v) if isinstance(v, list) else v for v in value)
        kwargs[key] = value
    return cls(**kwargs)


def load_spec(run_dir: str | pathlib.Path) -> RunSpec:
    path = pathlib.Path(run_dir) / "config.json"
    if not path.exists():
        raise RunError(f"{run_dir} is not a run directory (no config.json)")
    try:
        return RunSpec.from_json(path.read_text())
    except (ValueError, TypeError) as err:
        raise RunError(f"{path} is not a valid run config: {err}") from None


def on_backend(spec: RunSpec, physics_backend: str | None) -> RunSpec:
    """`spec` with its env on `physics_backend` ('jax' | 'warp'); unchanged for None."""
    if physics_backend is None:
        return spec
    return dataclasses.replace(spec, env=dataclasses.replace(spec.env, physics_backend=physics_backend))


def default_env_config(ppo: PPOConfig) -> FPiHConfig:
    """The task a method trains on unless told otherwise: the paper's task with the method's controller."""
    return FPiHConfig(control=ppo.control)


def make_env(ppo: PPOConfig, env_config: FPiHConfig | None = None) -> FPiHEnv:
    """The fPiH env a method trains on; `env_config` (task settings, None: the method's default) must use
    the method's controller."""
    env_config = env_config or default_env_config(ppo)
    if env_config.control != ppo.control:
        raise ValueError(f"method {ppo.method!r} needs control={ppo.control!r}, env has {env_config.control!r}")
    return FPiHEnv(env_config)


def sized_for_batch(env_config: FPiHConfig, worlds: int) -> FPiHConfig:
    """`env_config` for vmapped calls of up to `worlds` envs: on MuJoCo Warp its shared contact buffer
    is sized for them (`FPiHConfig.warp_worlds`); on MJX-JAX it is returned unchanged."""
    if env_config.physics_backend != "warp":
        return env_config
    return dataclasses.replace(env_config, warp_worlds=int(worlds))


def batch_mesh(batch: int, physics_backend: str = "jax") -> jax.sharding.Mesh | None:
    """A 1-D mesh ('envs') over the most local devices that divide `batch` evenly; None if that is one,
    or for MuJoCo Warp, which steps its batch on one device here (its contact buffer is shared by the batch).

    On a CPU-only machine `import match_jax` gives JAX one CPU device per core (`match_jax._xla`)."""
    if physics_backend == "warp":
        return None
    devices = jax.devices()
    count = max(n for n in range(1, len(devices) + 1) if batch % n == 0)
    return None if count == 1 else jax.sharding.Mesh(np.array(devices[:count]), ("envs",))


def shard_batch(x: jax.Array, axis: int, mesh: jax.sharding.Mesh | None) -> jax.Array:
    """`x` split along `axis` over `mesh` (as given by `batch_mesh`); unchanged if mesh is None."""
    if mesh is None:
        return x
    spec = jax.sharding.PartitionSpec(*([None] * axis), "envs")
    return jax.device_put(x, jax.sharding.NamedSharding(mesh, spec))


def shard_envs(state: TrainState, physics_backend: str = "jax") -> TrainState:
    """Place the env axis (axis 1 of env_state leaves) across local devices; the rest is replicated.

    Uses `batch_mesh(num_envs)`; a no-op on one device. The jitted chunk then runs SPMD over the
    devices (jax.sharding)."""
    mesh = batch_mesh(state.episode_success.shape[1], physics_backend)
    if mesh is None:
        return state
    replicated = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())

    def place(x):
        # Empty leaves (MJX's unused act/tendon/sensor arrays) stay replicated: that is how the jitted
        # chunk returns them, so the next call finds the same input shardings and does not recompile.
        return shard_batch(x, 1, mesh) if x.ndim >= 2 and x.size else jax.device_put(x, replicated)

    env_state = jax.tree_util.tree_map(place, state.env_state)
    rest = jax.tree_util.tree_map(lambda x: jax.device_put(x, replicated), state._replace(env_state=None))
    return rest._replace(env_state=env_state, episode_success=place(state.episode_success))


class Programs:
    """The env, trainer and jitted init / train_chunk of one (PPOConfig, FPiHConfig), built once per
    process by `programs`: every Run of that configuration (a resume, another run directory, a
    policy load for evaluation) traces and compiles them once."""

    def __init__(self, ppo: PPOConfig, env_config: FPiHConfig | None):
        self.env = make_env(ppo, env_config)
        self.trainer: Trainer = make_trainer(ppo, self.env, batch_mesh(ppo.num_envs, self.env.config.physics_backend))
        self.init = jax.jit(self.trainer.init)
        self.chunk = jax.jit(self.trainer.train_chunk, donate_argnums=0)
        self._shapes: dict[int, TrainState] = {}

    def state_shapes(self, num_seeds: int) -> TrainState:
        """The abstract TrainState (shapes and dtypes) of `num_seeds` seeds."""
        if num_seeds not in self._shapes:
            keys = jax.ShapeDtypeStruct((num_seeds, 2), jax.numpy.uint32)
            self._shapes[num_seeds] = jax.eval_shape(self.trainer.init, keys)
        return self._shapes[num_seeds]


def program_config(ppo: PPOConfig, env_config: FPiHConfig | None = None) -> tuple[PPOConfig, FPiHConfig]:
    """The configuration a run's compiled programs depend on: `ppo` and its env config (None: the
    method's default) with what the programs take as arguments set to fixed values: the step budget (it
    only sets how many iterations the host runs) and the `RuntimeValues` (SSL weight of the 'joint'
    phase, break force, hole-observation noise). Configurations with the same program_config share
    their compiled programs; a Run passes its own values (`RuntimeValues.of`)."""
    env_config = default_env_config(ppo) if env_config is None else env_config
    fixed = {"total_steps": PPOConfig.total_steps}
    if ppo.ssl_phase == "joint" and ppo.method in ("hybrid", "match"):
        fixed["ssl_coef"] = SSL_BETA  # any weight > 0 keeps the term in the loss; its value is an argument
    env_config = dataclasses.replace(env_config, break_force=FPiHConfig.break_force,
                                     hole_obs_noise=FPiHConfig.hole_obs_noise)
    return dataclasses.replace(ppo, **fixed), env_config


@functools.lru_cache(maxsize=8)
def _programs(ppo: PPOConfig, env_config: FPiHConfig) -> Programs:
    return Programs(ppo, env_config)


def programs(ppo: PPOConfig, env_config: FPiHConfig | None = None) -> Programs:
    """The Programs of a configuration's `program_config`, shared by all Runs of it in this process (the
    8 latest kept). Their init and chunk take the run's `RuntimeValues` as their last argument."""
    return _programs(*program_config(ppo, env_config))


class Run:
    """A run directory with its trainer and compiled functions (used by `train` and the tests)."""

    def __init__(self, spec: RunSpec, run_dir: str | pathlib.Path):
        self.spec = spec
        self.dir = pathlib.Path(run_dir)
        env_config = sized_for_batch(spec.env, spec.ppo.num_envs * spec.num_seeds)  # the seeds step as one batch
        self.programs = programs(spec.ppo, env_config)
        self.values = RuntimeValues.of(spec.ppo, spec.env)
        self.env = make_env(spec.ppo, env_config)  # the run's own task settings (the programs' are fixed)
        self.trainer: Trainer = self.programs.trainer

    def initial_state(self) -> TrainState:
        keys = jax.random.split(jax.random.PRNGKey(self.spec.seed), self.spec.num_seeds)
        return self.programs.init(keys, self.values)

    def chunk(self, state: TrainState):
        return self.programs.chunk(state, self.values)

    def restore_latest(self) -> TrainState:
        return checkpoints.restore(checkpoints.latest_dir(self.dir), self.programs.state_shapes(self.spec.num_seeds))

    def save_latest(self, state: TrainState) -> None:
        checkpoints.save(checkpoints.latest_dir(self.dir), int(np.asarray(state.iteration)[0]), state)

    def policy_target(self):
        """Abstract structure of one seed's saved policy: {'params', 'policy_stats', 'critic_stats'}."""
        target = _policy_of(self.programs.state_shapes(1))
        return jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), target)


class _CheckpointWriter:
    """Runs one checkpoint write at a time on a background thread. `submit` and `wait` first finish
    the write in flight and re-raise its error, if any, in the caller's thread."""

    def __init__(self):
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="checkpoint")
        self._pending: concurrent.futures.Future | None = None

    def submit(self, fn, *args) -> None:
        self.wait()
        self._pending = self._pool.submit(fn, *args)

    def wait(self) -> None:
        pending = self._pending
        if pending is None:
            return
        concurrent.futures.wait([pending])  # a Ctrl-C here leaves the write pending for close()
        self._pending = None
        pending.result()

    def close(self) -> None:
        try:
            self.wait()
        finally:
            self._pool.shutdown()


def _host_copy(tree):
    """A host (numpy) copy of `tree` that owns its memory: the next chunk donates the device buffers,
    which on CPU a plain `device_get` may alias."""
    return jax.tree_util.tree_map(lambda x: np.array(x, copy=True), jax.device_get(tree))


def _write_checkpoints(run: "Run", host_state: TrainState, new_best: list[tuple[int, dict]]) -> None:
    """Seed i's best policy and record for each (i, record) in `new_best`, then the latest full state."""
    iteration = int(host_state.iteration[0])
    for i, record in new_best:
        checkpoints.save(checkpoints.best_dir(run.dir, i), iteration, _seed_slice(_policy_of(host_state), i))
        checkpoints.write_best_record(run.dir, i, record)
    run.save_latest(host_state)


def _policy_of(state: TrainState) -> dict:
    return {"params": state.params, "policy_stats": state.policy_stats, "critic_stats": state.critic_stats}


def _seed_slice(tree, i: int):
    return jax.tree_util.tree_map(lambda x: x[i], tree)


def _rows(metrics: dict, seed_base: int) -> list[dict]:
    """One dict per (iteration, seed) from chunk metrics of shape (iterations, seeds)."""
    metrics = {k: np.asarray(v) for k, v in jax.device_get(metrics).items()}
    iterations, seeds = metrics["iteration"].shape
    rows = []
    for t in range(iterations):
        for s in range(seeds):
            row = {"seed_index": s, "seed": seed_base + s}
            for k in LOGGED:
                v = float(metrics[k][t, s])
                row[k] = int(v) if k in ("iteration", "env_steps", "episodes") else (None if math.isnan(v) else v)
            rows.append(row)
    return rows


def _truncate_metrics(path: pathlib.Path, last_iteration: int) -> None:
    if not path.exists():
        return
    kept = [line for line in path.read_text().splitlines()
            if line.strip() and json.loads(line)["iteration"] <= last_iteration]
    path.write_text("".join(line + "\n" for line in kept))


def _write_csv(jsonl: pathlib.Path, csv_path: pathlib.Path) -> None:
    rows = [json.loads(line) for line in jsonl.read_text().splitlines() if line.strip()]
    if not rows:
        return
    with csv_path.open("w", newline="") as f:
        # every key of every row, in order of appearance (a run resumed by a newer version logs more columns)
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for row in rows for k in row)))
        writer.writeheader()
        writer.writerows(rows)


def read_metrics(run_dir: str | pathlib.Path) -> list[dict]:
    """The rows of a run's metrics.jsonl; a last line still being written is left out."""
    path = pathlib.Path(run_dir) / "metrics.jsonl"
    lines = [line for line in path.read_text().splitlines() if line.strip()] if path.exists() else []
    rows = []
    for number, line in enumerate(lines, 1):
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            if number == len(lines):
                break
            raise RunError(f"{path} line {number} is not a JSON row: {line[:80]!r}") from None
    return rows


class TrainingStopped(KeyboardInterrupt):
    """Raised by `train` when Ctrl-C or SIGTERM stopped it after the running chunk, whose metric rows and
    checkpoints were written as at any chunk's end; `summary` is the dict train would have returned."""

    def __init__(self, summary: dict):
        super().__init__(f"stopped after iteration {summary['iterations']}")
        self.summary = summary


def holds_run(run_dir: str | pathlib.Path) -> bool:
    """Whether `run_dir` holds a run's training state (a latest checkpoint to resume from)."""
    return checkpoints.latest_step(checkpoints.latest_dir(pathlib.Path(run_dir))) is not None


def train(spec: RunSpec | None, run_dir: str | pathlib.Path, resume: bool = False, progress: bool = True,
          max_chunks: int | None = None, time_budget_s: float | None = None, total_steps: int | None = None,
          on_rows=None) -> dict:
    """Train (or, with resume=True, continue) a run in `run_dir`; returns a summary dict.

    With resume the spec is read from run_dir/config.json (`spec` may be None); `total_steps` (env steps
    per seed) then replaces its step budget, to train a finished run further (not for a run whose
    learning rate decays over its budget). `max_chunks` stops
    after that many chunks (tests); `time_budget_s` stops after the first chunk that ends more than
    that many seconds (wall clock, compilation included) after the call began. Either way the run is
    checkpointed and can be resumed later. `on_rows(rows)`, if given, gets each chunk's metric rows
    once they are in metrics.jsonl (e.g. `tb_logging.TensorBoardLogger`).

    Ctrl-C or SIGTERM (in the main thread) lets the running chunk finish, writes its rows and
    checkpoints, then raises `TrainingStopped` (a KeyboardInterrupt); a second Ctrl-C raises
    KeyboardInterrupt without writing the running chunk. A directory that cannot be a run directory
    (it already holds a run, cannot be written) is a RunError before anything is compiled.
    """
    if time_budget_s is not None and not time_budget_s > 0:
        raise RunError(f"time budget must be > 0 seconds, got {time_budget_s}")
    if total_steps is not None and not resume:
        raise RunError("total_steps replaces a resumed run's budget; a new run takes it from its spec")
    call_start = time.time()
    run_dir = pathlib.Path(run_dir)
    latest = checkpoints.latest_dir(run_dir)
    if resume:
        if not run_dir.is_dir():
            raise RunError(f"cannot resume: {run_dir} does not exist")
        spec = load_spec(run_dir)
        if checkpoints.latest_step(latest) is None:
            raise RunError(f"cannot resume: no checkpoint in {latest}")
        _check_writable(run_dir)
    else:
        if spec is None:
            raise RunError("train() needs a RunSpec unless resume=True")
        if holds_run(run_dir):
            raise RunError(f"{run_dir} already holds a run: continue it with resume=True, or choose another directory")
        _check_writable(run_dir)
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            (run_dir / "config.json").write_text(spec.to_json())
            (run_dir / "metrics.jsonl").write_text("")
        except OSError as err:
            raise RunError(f"cannot write the run directory {run_dir}: {err.strerror or err}") from None

    if total_steps is not None and total_steps != spec.ppo.total_steps:
        if spec.ppo.learning_rate_end is not None:
            raise RunError(f"{run_dir} decays its learning rate over its budget of {spec.ppo.total_steps} env steps; "
                           "a new budget would restart the decay, so it cannot take one")
        spec = dataclasses.replace(spec, ppo=dataclasses.replace(spec.ppo, total_steps=total_steps))
    run = Run(spec, run_dir)
    ppo = spec.ppo
    chunks_total = -(-ppo.num_iterations // ppo.iterations_per_chunk)  # training runs whole chunks
    steps_per_chunk = ppo.steps_per_iteration * ppo.iterations_per_chunk
    clock_offset = 0.0  # wall_clock_s adds up over the calls that trained the run
    if resume:
        state = run.restore_latest()
        if total_steps is not None:
            trained = int(np.asarray(state.env_steps)[0])
            if chunks_total * steps_per_chunk < trained:  # a finished run trained its budget rounded up to chunks
                raise RunError(f"total steps {total_steps} is below the {trained} env steps per seed {run_dir} "
                               "has trained")
            (run_dir / "config.json").write_text(spec.to_json())
        _truncate_metrics(run_dir / "metrics.jsonl", int(np.asarray(state.iteration)[0]))
        clock_offset = _last_wall_clock(run_dir)
    else:
        state = run.initial_state()
    state = shard_envs(state, run.env.config.physics_backend)
    best = [(checkpoints.read_best_record(run_dir, i) or {}).get("success_rate", -1.0) for i in range(spec.num_seeds)]

    done_chunks = int(np.asarray(state.iteration)[0]) // ppo.iterations_per_chunk
    bar = None
    if progress:
        from tqdm.auto import tqdm
        # tqdm's own rate would count steps per seed and the compilation; the postfix gives env steps/s instead
        bar = tqdm(total=chunks_total * steps_per_chunk, initial=done_chunks * steps_per_chunk, unit="step",
                   unit_scale=True, desc=f"{ppo.method} x{spec.num_seeds} seeds", dynamic_ncols=True,
                   bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} env steps per seed "
                              "[{elapsed}{postfix}]")
    start, steps_this_session, chunks_run, first_chunk_end = time.time(), 0, 0, None
    last_rows: list[dict] = []
    writer = _CheckpointWriter()
    stop = _StopSignals(_say(bar))
    stop.install()
    try:
        note = _compile_note(run) if bar is not None else None
        if note:
            bar.set_postfix_str(note)
        while (not stop.requested and done_chunks < chunks_total and (max_chunks is None or chunks_run < max_chunks)
               and (time_budget_s is None or chunks_run == 0 or time.time() - call_start < time_budget_s)):
            state, metrics = run.chunk(state)
            rows = _rows(metrics, spec.seed)
            now = time.time()
            with (run_dir / "metrics.jsonl").open("a") as f:
                for row in rows:
                    row["wall_clock_s"] = round(clock_offset + now - start, 2)
                    f.write(json.dumps(row) + "\n")
            if on_rows is not None:
                on_rows(rows)
            done_chunks += 1
            chunks_run += 1
            first_chunk_end = first_chunk_end or now
            steps_this_session += steps_per_chunk * spec.num_seeds
            last_rows = rows[-spec.num_seeds:]
            iteration = last_rows[0]["iteration"]
            new_best = []
            for i, row in enumerate(last_rows):
                # A chunk in which no episode ended scores -0.5: every seed gets a best checkpoint.
                rate = -0.5 if row["success_rate"] is None else row["success_rate"]
                if rate >= best[i]:
                    best[i] = rate
                    new_best.append((i, {"iteration": iteration, "env_steps": row["env_steps"],
                                         "success_rate": rate, "break_rate": row["break_rate"]}))
            writer.submit(_write_checkpoints, run, _host_copy(state), new_best)
            _write_csv(run_dir / "metrics.jsonl", run_dir / "metrics.csv")
            if bar is not None:
                # env steps of all seeds per second over this call's chunks after the first (which compiles)
                rate = None if chunks_run < 2 else \
                    steps_per_chunk * spec.num_seeds * (chunks_run - 1) / max(now - first_chunk_end, 1e-9)
                left = None if rate is None else (chunks_total - done_chunks) * steps_per_chunk * spec.num_seeds / rate
                bar.set_postfix_str(_progress_note(last_rows, rate, left), refresh=False)
                bar.update(steps_per_chunk)
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        writer.wait()  # the last chunk's checkpoint is complete before we say what can be resumed
        _say_how_to_resume(run_dir)
        raise
    finally:
        try:
            writer.close()
        finally:
            stop.uninstall()
    if bar is not None:
        bar.close()
    elapsed = time.time() - start
    summary = {
        "run_dir": str(run_dir),
        "iterations": int(np.asarray(state.iteration)[0]),
        "env_steps_per_seed": int(np.asarray(state.env_steps)[0]),
        "finished": done_chunks >= chunks_total,
        "wall_clock_s": elapsed,
        "env_steps_per_s": steps_this_session / max(elapsed, 1e-9),
        "last_success_rate": [r["success_rate"] for r in last_rows],
        "last_break_rate": [r["break_rate"] for r in last_rows],
        "best_success_rate": [None if rate < 0 else rate for rate in best],  # None: no episode ended yet
    }
    if stop.requested:
        _say_how_to_resume(run_dir, summary["iterations"])
        raise TrainingStopped(summary)
    return summary


def _check_writable(run_dir: pathlib.Path) -> None:
    problem = unwritable(run_dir, directory=True)
    if problem:
        raise RunError(f"cannot write the run directory {run_dir}: {problem}")


def _last_wall_clock(run_dir: pathlib.Path) -> float:
    """The wall_clock_s of the last metrics row (0 if none): where a resumed run's clock continues."""
    rows = read_metrics(run_dir)
    return float(rows[-1].get("wall_clock_s") or 0.0) if rows else 0.0


def _say_how_to_resume(run_dir: pathlib.Path, stopped_after: int | None = None) -> None:
    """The line a stop prints: after Ctrl-C/SIGTERM let the chunk that ended at iteration `stopped_after`
    be saved, or (None) after an interruption that left the running chunk unsaved."""
    what = "interrupted" if stopped_after is None else "stopped"
    resume = f"resume with: python train.py --resume --out {run_dir}"
    if not holds_run(run_dir):
        print(f"{what} before the first checkpoint: nothing to resume; start {run_dir} again")
    elif stopped_after is None:
        print(f"interrupted; the latest checkpoint is kept: {resume}")
    else:
        print(f"stopped after iteration {stopped_after}, its metrics and checkpoint saved: {resume}")


def _compile_note(run: Run) -> str | None:
    """What the first chunk's wait is, for the progress bar: compiling (unless this process already
    compiled the chunk), and whether JAX's persistent compilation cache is on."""
    compiled = getattr(run.programs.chunk, "_cache_size", lambda: 0)()
    if compiled:
        return None
    from match_jax import compile_cache

    return f"compiling the first chunk ({compile_cache.describe()})"


def _progress_note(rows: list[dict], env_steps_per_s: float | None, left_s: float | None) -> str:
    note = f"success {_fmt_mean(rows, 'success_rate')}, breaks {_fmt_mean(rows, 'break_rate')}"
    if env_steps_per_s is not None:
        from tqdm import tqdm
        note += f", {env_steps_per_s:,.0f} env steps/s, {tqdm.format_interval(left_s)} left"
    return note


def _say(bar):
    """A print to stderr that does not break the progress bar `bar` (None: no bar)."""
    if bar is None:
        return lambda message: print(message, file=sys.stderr, flush=True)
    return lambda message: bar.write(message, file=sys.stderr)


class _StopSignals:
    """Ctrl-C (SIGINT) and SIGTERM while `train` runs: the first sets `requested` (its signal number),
    and training stops once the running chunk is written; a second raises KeyboardInterrupt. Python runs
    a signal handler only when the main thread is back in Python, i.e. once the running chunk (one
    blocking XLA call) returns; a thread woken through `signal.set_wakeup_fd` says at once, through `say`,
    that the stop is coming. Only in the main thread; elsewhere signals are left alone."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, say):
        self.requested: int | None = None
        self._say = say
        self._previous: dict = {}
        self._pipe: tuple[int, int] | None = None
        self._previous_wakeup = -1
        self._thread: threading.Thread | None = None

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for signum in self.SIGNALS:
            self._previous[signum] = signal.signal(signum, self.handle)
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        try:
            self._previous_wakeup = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        except (ValueError, OSError):  # no wake-up descriptor here: no notice before the chunk returns
            os.close(read_fd)
            os.close(write_fd)
            return
        self._pipe = (read_fd, write_fd)
        self._thread = threading.Thread(target=self._watch, args=(read_fd,), name="stop-notice", daemon=True)
        self._thread.start()

    def handle(self, signum, frame) -> None:
        if self.requested is not None:
            raise KeyboardInterrupt(f"signal {signum}")
        self.requested = signum

    def _watch(self, read_fd: int) -> None:
        while True:
            data = os.read(read_fd, 64)
            if not data:  # uninstall() closed the pipe
                return
            signals = [byte for byte in data if byte in self.SIGNALS]
            if signals:
                self._say(f"{signal.Signals(signals[0]).name}: stopping once the running chunk is done and saved "
                          "(Ctrl-C again: stop without saving it)")
                return

    def uninstall(self) -> None:
        if self._pipe is not None:
            signal.set_wakeup_fd(self._previous_wakeup)
            read_fd, write_fd = self._pipe
            os.close(write_fd)  # ends the watcher thread
            self._thread.join(timeout=5)
            os.close(read_fd)
            self._pipe = None
        for signum, previous in self._previous.items():
            if previous is not None:  # None: a handler not set from Python, which cannot be put back
                signal.signal(signum, previous)
        self._previous = {}


def _fmt_mean(rows: list[dict], key: str) -> str:
    values = [r[key] for r in rows if r[key] is not None]
    return f"{100 * sum(values) / len(values):.0f}%" if values else "-"


def _policy_run(run_dir: str | pathlib.Path, which: str, physics_backend: str | None = None) -> Run:
    if which not in ("best", "latest"):
        raise RunError(f"checkpoint must be 'best' or 'latest', got {which!r}")
    return Run(on_backend(load_spec(run_dir), physics_backend), run_dir)  # the policies do not depend on it


def _restore_policies(run: Run, which: str, seed_indices) -> list[dict]:
    if is_exported(run.dir):
        if which != "best":
            raise RunError(f"{run.dir} holds exported best actors only; use the 'best' checkpoint, not {which!r}")
        return [_load_actor(run, i) for i in seed_indices]
    if which == "best":
        target = run.policy_target()
        return [checkpoints.restore(checkpoints.best_dir(run.dir, i), target) for i in seed_indices]
    policy = _policy_of(run.restore_latest())
    return [_seed_slice(policy, i) for i in seed_indices]


ACTORS_DIR = "actors"


def is_exported(run_dir: str | pathlib.Path) -> bool:
    """Whether `run_dir` is an exported run (`export_actors`): config, metrics and best actors, no checkpoints."""
    run_dir = pathlib.Path(run_dir)
    return (run_dir / ACTORS_DIR).is_dir() and not checkpoints.run_checkpoints_dir(run_dir).exists()


def best_record(run_dir: str | pathlib.Path, seed_index: int) -> dict | None:
    """The record of one seed's best checkpoint ({'iteration', 'env_steps', 'success_rate', ...}), from
    the run's checkpoints or, in an exported run, from `actors/seed<i>.json`; None if there is none yet."""
    run_dir = pathlib.Path(run_dir)
    if is_exported(run_dir):
        path = record_path(run_dir, seed_index)
        return json.loads(path.read_text()) if path.exists() else None
    return checkpoints.read_best_record(run_dir, seed_index)


def actor_path(run_dir: pathlib.Path, seed_index: int) -> pathlib.Path:
    """Seed `seed_index`'s actor parameters and normaliser in an exported run (flax msgpack)."""
    return run_dir / ACTORS_DIR / f"seed{seed_index}.msgpack"


def record_path(run_dir: pathlib.Path, seed_index: int) -> pathlib.Path:
    """Seed `seed_index`'s best-checkpoint record in an exported run (JSON)."""
    return run_dir / ACTORS_DIR / f"seed{seed_index}.json"


def export_actors(run_dir: str | pathlib.Path, out_dir: str | pathlib.Path) -> pathlib.Path:
    """Write the shippable part of a run to `out_dir`: config.json, metrics.jsonl / .csv, and per seed
    the best checkpoint's actor parameters and observation normaliser (`actors/seed<i>.msgpack`, flax
    msgpack) with its record (`actors/seed<i>.json`). No critic, no optimizer state: an exported run
    evaluates (eval.py, `load_policies`) but does not resume."""
    run, policies = load_policies(run_dir, "best")
    out = pathlib.Path(out_dir)
    (out / ACTORS_DIR).mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(run.spec.to_json())
    for name in ("metrics.jsonl", "metrics.csv"):
        if (run.dir / name).exists():
            (out / name).write_bytes((run.dir / name).read_bytes())
    for i, policy in enumerate(policies):
        tree = jax.device_get({"actor": policy["params"]["actor"], "policy_stats": policy["policy_stats"]})
        actor_path(out, i).write_bytes(flax.serialization.msgpack_serialize(flax.serialization.to_state_dict(tree)))
        record_path(out, i).write_text(json.dumps(best_record(run.dir, i), indent=2))
    return out


def _load_actor(run: Run, seed_index: int) -> dict:
    """{'params': {'actor'}, 'policy_stats'} of one seed of an exported run."""
    path = actor_path(run.dir, seed_index)
    if not path.exists():
        raise RunError(f"{path} is missing: the exported run has no actor for seed index {seed_index}")
    full = run.policy_target()
    target = {"actor": full["params"]["actor"], "policy_stats": full["policy_stats"]}
    try:
        tree = flax.serialization.from_state_dict(target, flax.serialization.msgpack_restore(path.read_bytes()))
    except Exception as err:  # noqa: BLE001  (any decoding error: one line naming the file)
        raise RunError(f"{path} is unreadable ({type(err).__name__}: {str(err).splitlines()[0][:200]})") from None
    for want, got in zip(jax.tree_util.tree_leaves(target), jax.tree_util.tree_leaves(tree)):
        if tuple(want.shape) != tuple(np.shape(got)):
            raise RunError(f"{path} does not match {run.dir / 'config.json'}: a leaf of shape {np.shape(got)} "
                           f"where the config gives {tuple(want.shape)}")
    tree = jax.tree_util.tree_map(lambda want, x: jax.numpy.asarray(x, want.dtype), target, tree)
    return {"params": {"actor": tree["actor"]}, "policy_stats": tree["policy_stats"]}


def load_policies(run_dir: str | pathlib.Path, which: str = "best",
                  physics_backend: str | None = None) -> tuple[Run, list[dict]]:
    """(Run, [{'params', 'policy_stats', 'critic_stats'} per seed]) from the seeds' best checkpoints or
    the latest one; the Run (env, trainer) is built once for all seeds, its env on `physics_backend`
    ('jax' | 'warp'; None: the run's own). From an exported run (`export_actors`):
    [{'params': {'actor'}, 'policy_stats'}], the best actors only."""
    run = _policy_run(run_dir, which, physics_backend)
    return run, _restore_policies(run, which, range(run.spec.num_seeds))


def load_policy(run_dir: str | pathlib.Path, seed_index: int, which: str = "best",
                physics_backend: str | None = None) -> tuple[Run, dict]:
    """(Run, {'params', 'policy_stats', 'critic_stats'}) of one seed, from its best or the latest
    checkpoint; the Run's env on `physics_backend` (None: the run's own)."""
    run = _policy_run(run_dir, which, physics_backend)
    if not 0 <= seed_index < run.spec.num_seeds:
        raise RunError(f"seed index {seed_index} out of range: {run_dir} has {run.spec.num_seeds} seeds")
    return run, _restore_policies(run, which, [seed_index])[0]

