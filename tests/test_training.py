"""Training on fPiH with the tiny preset: every method runs, checkpoints restore bit-identically,
an interrupted run resumes to the same result, the quickstart notebook runs, bad input gives one-line
errors."""

import match_jax  # noqa: F401

import dataclasses
import json
import math
import os
import pathlib
import re
import signal
import subprocess
import sys
import threading
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import train as train_cli
from match_jax.training import checkpoints
from match_jax.envs import FPiHConfig
from match_jax.envs.tasks import TASKS
from match_jax.envs.point_mass import PointMassConfig, PointMassEnv
from match_jax.rl.ppo import RuntimeValues, make_trainer
from match_jax.training.presets import get_preset
from match_jax.training import runs as training
from match_jax.training.runs import (Run, RunError, RunSpec, TrainingStopped, _CheckpointWriter, _StopSignals, export_actors,
                                load_policies, load_policy, read_metrics, train)

REPO = pathlib.Path(__file__).resolve().parents[1]


def _leaves_equal(a, b) -> bool:
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    return len(la) == len(lb) and all(
        np.shape(x) == np.shape(y) and np.asarray(x).dtype == np.asarray(y).dtype
        and np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True) for x, y in zip(la, lb))


@pytest.mark.parametrize("method", ["pose", "vices", "hybrid", "match", "match-ssl-after"])
def test_each_method_trains_and_checkpoints_restore_bit_identically(method, tmp_path):
    """Every method's trainer on the cheap PointMassEnv (with the method's action space): a chunk trains
    with finite losses, and the whole state, env included, restores bit-identically from a checkpoint.
    MATCH on the MJX env: the runner test below."""
    # match-ssl-after: MATCH with the SSL in its own steps after the PPO epochs (ssl_phase='after')
    overrides = dict(method="match", ssl_phase="after") if method == "match-ssl-after" else dict(method=method)
    ppo = get_preset("tiny", **overrides)
    trainer = make_trainer(ppo, PointMassEnv(PointMassConfig(control=ppo.control)))
    initial = jax.jit(trainer.init)(jax.random.split(jax.random.PRNGKey(0), 2))
    state, metrics = jax.jit(trainer.train_chunk)(initial)
    for key in ("loss", "policy_loss", "value_loss", "entropy"):
        assert np.all(np.isfinite(np.asarray(metrics[key]))), key
    assert int(state.iteration[0]) == 1 and int(state.env_steps[0]) == 4 * 8
    checkpoints.save(tmp_path / "latest", 1, state)
    target = jax.eval_shape(trainer.init, jax.ShapeDtypeStruct((2, 2), jax.numpy.uint32))
    restored = checkpoints.restore(tmp_path / "latest", target)
    assert _leaves_equal(restored, state)
    # a fresh state, a chunk's output and a restored one have the same types: one compile of the chunk
    types = lambda tree: jax.tree_util.tree_map(lambda x: (x.shape, x.dtype, x.weak_type), tree)  # noqa: E731
    assert types(initial) == types(state) == types(restored)


def test_ssl_weight_as_an_argument_trains_as_the_configured_weight():
    """The SSL weight passed at run time (`RuntimeValues`, how the suite's SSL and no-SSL runs share one
    program) trains exactly as the configured weight: beta 0 as an argument of a beta-1 trainer gives
    the no-SSL trainer's chunk, beta 1 another one."""
    ppo = get_preset("tiny", method="match", ssl_coef=1.0)
    env = PointMassEnv(PointMassConfig(control=ppo.control))
    shared = make_trainer(ppo, env)
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    start = jax.jit(shared.init)(keys)
    chunk = jax.jit(shared.train_chunk)
    values = RuntimeValues.of(ppo, None)
    without, m0 = chunk(start, values._replace(ssl_beta=jnp.float32(0.0)))
    with_ssl, m1 = chunk(start, values)
    nossl = make_trainer(dataclasses.replace(ppo, ssl_coef=0.0), env)
    reference, mref = jax.jit(nossl.train_chunk)(start)
    assert chunk._cache_size() == 1
    for a, b in zip(jax.tree_util.tree_leaves(without.params), jax.tree_util.tree_leaves(reference.params)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.asarray(m0["loss"]), np.asarray(mref["loss"]), rtol=1e-5)
    assert not np.allclose(np.asarray(m1["loss"]), np.asarray(m0["loss"]))  # the SSL term counts at beta 1


def test_runs_differing_in_ssl_break_force_or_noise_share_programs():
    """The suite's MATCH, MATCH (no SSL), MATCH (unbreakable) and a 2.5 mm-noise MATCH share one Programs
    (nothing compiled here); each Run keeps its own values and its own env settings."""
    base = RunSpec(ppo=get_preset("tiny", method="match"))
    variants = [base, RunSpec(ppo=get_preset("tiny", method="match", ssl_coef=0.0, total_steps=999)),
                RunSpec(ppo=base.ppo, env=FPiHConfig(control="hybrid", break_force=math.inf)),
                RunSpec(ppo=base.ppo, env=FPiHConfig(control="hybrid", hole_obs_noise=0.0025))]
    runs = [Run(spec, "unused") for spec in variants]
    assert all(run.programs is runs[0].programs for run in runs)
    assert [float(run.values.ssl_beta) for run in runs] == [pytest.approx(0.3), 0.0, pytest.approx(0.3), pytest.approx(0.3)]
    assert float(runs[2].values.break_force) == math.inf and runs[2].env.config.break_force == math.inf
    assert float(runs[3].values.hole_obs_noise) == pytest.approx(0.0025) and runs[3].env.config.hole_obs_noise == 0.0025
    others = [RunSpec(ppo=get_preset("tiny", method="hybrid")),
              RunSpec(ppo=get_preset("tiny", method="match", ssl_phase="after", ssl_coef=0.0)),
              RunSpec(ppo=base.ppo, env=FPiHConfig(control="hybrid", break_sampling="peak"))]
    assert all(Run(spec, "unused").programs is not runs[0].programs for spec in others)


def test_match_trains_through_the_runner_and_resumes_exactly(tmp_path, monkeypatch, capsys):
    """Two chunks straight vs one chunk, 'interrupt', resume, one more: identical metrics and state."""
    spec = RunSpec(ppo=get_preset("tiny", method="match", total_steps=4 * 32), num_seeds=2)
    straight, split = tmp_path / "straight", tmp_path / "split"
    train(spec, straight, progress=False, max_chunks=2)
    first = train(spec, split, progress=False, max_chunks=1)
    assert not first["finished"] and first["iterations"] == 1
    train(None, split, resume=True, progress=False, max_chunks=1)
    rows_a, rows_b = read_metrics(straight), read_metrics(split)
    assert len(rows_a) == len(rows_b) == 4  # 2 iterations x 2 seeds
    for a, b in zip(rows_a, rows_b):
        a.pop("wall_clock_s"), b.pop("wall_clock_s")
        assert a == b
        assert all(np.isfinite(a[k]) for k in ("loss", "policy_loss", "value_loss", "ssl_loss"))
    run = Run(spec, straight)
    assert _leaves_equal(run.restore_latest(), Run(spec, split).restore_latest())
    # the resolved config, a CSV and a best policy per seed are beside the checkpoints
    assert RunSpec.from_json((straight / "config.json").read_text()) == spec
    assert (straight / "metrics.csv").read_text().count("\n") == 5
    rows = [json.loads(line) for line in (straight / "metrics.jsonl").read_text().splitlines()]
    for row in rows:  # p(force) per axis on free-space axes: ~0.07 at initialisation
        assert 0.0 < row["p_force_free_axis"] < 0.2 and "p_force_contact_axis" in row
    for seed in range(2):
        record = checkpoints.read_best_record(straight, seed)
        assert record is not None and record["iteration"] in (1, 2)
        _, policy = load_policy(straight, seed, "best")
        assert set(policy) == {"params", "policy_stats", "critic_stats"}
    # the exported run (best actors and normalisers only) loads the same actors; it cannot resume
    exported = export_actors(straight, tmp_path / "exported")
    assert not (exported / "checkpoints").exists() and (exported / "metrics.jsonl").exists()
    _, shipped = load_policies(exported)
    _, full = load_policies(straight)
    for a, b in zip(shipped, full):
        assert set(a) == {"params", "policy_stats"} and set(a["params"]) == {"actor"}
        assert _leaves_equal(a["params"]["actor"], b["params"]["actor"])
        assert _leaves_equal(a["policy_stats"], b["policy_stats"])
    with pytest.raises(RunError, match="exported best actors only"):
        load_policies(exported, "latest")
    # eval.py on the run: every seed, the Table 1 columns, selection rates, a JSON document
    import eval as eval_cli
    out = tmp_path / "eval.json"
    assert eval_cli.main([str(straight), "--episodes", "4", "--json", str(out)]) == 0  # the notebook's size
    result = json.loads(out.read_text())
    assert result["seeds"] == 2 and len(result["per_seed"]) == 2
    for column in ("success_rate", "break_rate", "force_selected_free", "p_force_free"):
        assert column in result["aggregate"]
    assert 0.0 < result["aggregate"]["p_force_free"]["mean"] < 0.2  # barely trained: ~0.07 at initialisation
    assert sum(result["selection_profile"]["episodes"]) >= 8
    # a time budget that is already spent still runs one chunk, then stops, resumable
    budgeted = train(None, split, resume=True, progress=False, time_budget_s=1e-3)
    assert budgeted["iterations"] == 3 and not budgeted["finished"]
    # finishing: one more resume completes the 4-iteration budget
    done = train(None, split, resume=True, progress=False)
    assert done["finished"] and done["iterations"] == 4
    # a finished run trains further with a larger budget, which its config.json then records
    with pytest.raises(RunError, match="below the 128 env steps per seed"):
        train(None, split, resume=True, progress=False, total_steps=3 * 32)
    # a budget that whole iterations round up to what it trained is the finished run (nothing to train)
    again = train(None, split, resume=True, progress=False, total_steps=4 * 32 - 5)
    assert again["finished"] and again["iterations"] == 4 and len(read_metrics(split)) == 8
    further = train(None, split, resume=True, progress=False, total_steps=5 * 32)
    assert further["finished"] and further["iterations"] == 5 and further["env_steps_per_seed"] == 5 * 32
    assert RunSpec.from_json((split / "config.json").read_text()).ppo.total_steps == 5 * 32
    assert len(read_metrics(split)) == 10
    assert all(row["learning_rate"] == pytest.approx(spec.ppo.learning_rate) for row in read_metrics(split))
    # a run whose learning rate decays over its budget cannot take a new one (the decay would restart)
    import shutil
    decaying = shutil.copytree(split, tmp_path / "decaying")
    decayed = dataclasses.replace(spec, ppo=dataclasses.replace(spec.ppo, total_steps=5 * 32, learning_rate_end=0.0))
    (decaying / "config.json").write_text(decayed.to_json())
    with pytest.raises(RunError, match="decays its learning rate over its budget of 160 env steps"):
        train(None, decaying, resume=True, progress=False, total_steps=6 * 32)
    # Ctrl-C during a chunk: the message says whether there is a checkpoint to resume from
    def interrupted_chunk(self, state):
        raise KeyboardInterrupt
    monkeypatch.setattr(Run, "chunk", interrupted_chunk)
    capsys.readouterr()
    for run_spec, run_dir, resume, expected in ((spec, tmp_path / "fresh", False, "nothing to resume"),
                                                (None, straight, True, "resume with: python train.py --resume")):
        with pytest.raises(KeyboardInterrupt):
            train(run_spec, run_dir, resume=resume, progress=False)
        assert expected in capsys.readouterr().out


# The runner test's configuration: its compiled programs serve the tests below in the same process.
TINY_2_SEEDS = RunSpec(ppo=get_preset("tiny", method="match", total_steps=4 * 32), num_seeds=2)


def test_a_stop_signal_keeps_the_running_chunk_and_the_clock_adds_up(tmp_path, monkeypatch, capsys):
    """SIGTERM while the first chunk runs: a notice at once, the chunk finishes, its rows and checkpoints
    are written, then TrainingStopped with the resume line; the signal handlers are restored. A resume
    continues the wall clock from the last row."""
    real_chunk = Run.chunk

    def chunk_under_sigterm(self, state):
        os.kill(os.getpid(), signal.SIGTERM)  # Python runs the handler here, inside the chunk's call
        return real_chunk(self, state)

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers are set in the main thread only")  # a SIGTERM here would end the process
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(Run, "chunk", chunk_under_sigterm)
    run_dir = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt) as stopped:
        train(TINY_2_SEEDS, run_dir, progress=False)
    assert isinstance(stopped.value, TrainingStopped)
    assert stopped.value.summary["iterations"] == 1 and not stopped.value.summary["finished"]
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers
    assert [row["iteration"] for row in read_metrics(run_dir)] == [1, 1]
    assert checkpoints.latest_step(checkpoints.latest_dir(run_dir)) == 1
    assert checkpoints.read_best_record(run_dir, 1)["iteration"] == 1
    captured = capsys.readouterr()
    assert f"stopped after iteration 1, its metrics and checkpoint saved: resume with: python train.py --resume " \
           f"--out {run_dir}" in captured.out
    assert "SIGTERM: stopping once the running chunk is done and saved" in captured.err
    # the resumed run's clock goes on from the last row's (set far ahead here to tell it from a restart)
    monkeypatch.setattr(Run, "chunk", real_chunk)
    rows = read_metrics(run_dir)
    (run_dir / "metrics.jsonl").write_text("".join(json.dumps({**row, "wall_clock_s": 1000.0}) + "\n" for row in rows))
    train(None, run_dir, resume=True, progress=False, max_chunks=1)
    later = [row["wall_clock_s"] for row in read_metrics(run_dir) if row["iteration"] == 2]
    assert len(later) == 2 and all(1000.0 < clock < 1000.0 + 600 for clock in later)


def test_a_second_stop_signal_interrupts_at_once():
    """The first signal only asks for a stop; a second raises KeyboardInterrupt (an impatient Ctrl-C)."""
    said = []
    stop = _StopSignals(said.append)
    stop.handle(signal.SIGTERM, None)
    assert stop.requested == signal.SIGTERM
    with pytest.raises(KeyboardInterrupt):
        stop.handle(signal.SIGINT, None)


def test_progress_bar_shows_one_rate_without_the_compilation(tmp_path, capsys):
    """The bar's only rate is env steps/s of all seeds over the chunks after the first (tqdm's own rate,
    per seed and with the compilation, is off), with the time left at that rate."""
    train(TINY_2_SEEDS, tmp_path / "run", progress=True, max_chunks=3)
    updates = capsys.readouterr().err.replace("\r", "\n").splitlines()
    assert not [line for line in updates if re.search(r"\d(step|it)/s|s/(step|it)", line)]
    rated = [line for line in updates if "env steps/s" in line]
    assert rated and all(re.search(r"success -|success \d+%", line) for line in rated)
    assert re.search(r"[\d,]+ env steps/s, \d\d:\d\d left", rated[-1])
    assert "96.0/128 env steps per seed" in rated[-1]
    assert not any("env steps/s" in line for line in updates if "32.0/128" in line)  # one chunk: no rate yet


def test_the_first_chunk_says_it_compiles_and_whether_the_cache_is_on(monkeypatch):
    from types import SimpleNamespace

    from match_jax import compile_cache

    def run_with(compiled):
        return SimpleNamespace(programs=SimpleNamespace(chunk=SimpleNamespace(_cache_size=lambda: compiled)))

    assert training._compile_note(run_with(1)) is None  # compiled before in this process: nothing to say
    note = training._compile_note(run_with(0))
    assert note == f"compiling the first chunk (compilation cache on: {jax.config.jax_compilation_cache_dir})"
    cache_dir = jax.config.jax_compilation_cache_dir
    try:
        jax.config.update("jax_compilation_cache_dir", None)
        assert compile_cache.describe() == "compilation cache off"
    finally:
        jax.config.update("jax_compilation_cache_dir", cache_dir)


@pytest.mark.slow
def test_ctrl_c_while_train_py_compiles_keeps_the_first_chunk(tmp_path):
    """train.py in a fresh process with the compilation cache off; Ctrl-C (SIGINT) once the bar says the
    first chunk compiles: the notice, then that chunk saved (rows and checkpoint of iteration 1), the
    resume line and exit status 130."""
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(REPO), MATCH_JAX_COMPILATION_CACHE="0")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    command = [sys.executable, "train.py", "--method", "match", "--preset", "tiny", "--total-steps", "128",
               "--out", str(out)]
    proc = subprocess.Popen(command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    err = bytearray()

    def read_stderr():  # the bar rewrites its line with \r: read byte by byte
        while byte := proc.stderr.read(1):
            err.extend(byte)

    reader = threading.Thread(target=read_stderr)
    reader.start()
    deadline = time.time() + 300
    while b"compiling the first chunk" not in err and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)
    assert b"compiling the first chunk (compilation cache off)" in err, err.decode()[-2000:]
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=600)
    finally:
        proc.kill()
    reader.join(10)
    stdout = proc.stdout.read()
    text = err.decode()
    assert proc.returncode == 130, text[-3000:]
    assert "SIGINT: stopping once the running chunk is done and saved" in text
    assert "Traceback" not in text
    assert f"stopped after iteration 1, its metrics and checkpoint saved: resume with: python train.py --resume " \
           f"--out {out}" in stdout.decode()
    assert [row["iteration"] for row in read_metrics(out)] == [1]
    assert checkpoints.latest_step(checkpoints.latest_dir(out)) == 1


def test_quickstart_notebook_runs(tmp_path, monkeypatch):
    notebook = json.loads((REPO / "notebooks" / "quickstart.ipynb").read_text())
    code = "\n\n".join("".join(cell["source"]) for cell in notebook["cells"] if cell["cell_type"] == "code")
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(code, "quickstart.ipynb", "exec"), namespace)
    assert namespace["summary"]["finished"]
    assert namespace["figure_path"].exists()
    assert namespace["result"]["seeds"] == 2


def test_cli_errors_are_one_line(tmp_path, capsys):
    def error_of(argv):
        with pytest.raises(SystemExit) as exit_info:
            train_cli.main(argv)
        assert exit_info.value.code == 2
        return capsys.readouterr().err.strip().splitlines()[-1]

    assert "invalid choice: 'sac'" in error_of(["--method", "sac", "--out", str(tmp_path / "a")])
    assert "--total-steps must be a positive integer, got 0" in error_of(
        ["--method", "match", "--total-steps", "0", "--out", str(tmp_path / "a")])
    assert "--time-budget-min must be a positive number of minutes, got -1.0" in error_of(
        ["--method", "match", "--time-budget-min", "-1", "--out", str(tmp_path / "a")])
    assert "learning_rate_end must be a finite number >= 0 or None, got -0.001" in error_of(
        ["--method", "match", "--learning-rate-end=-1e-3", "--out", str(tmp_path / "a")])
    assert "initial_log_std must be in (-5, 1) (min_log_std, max_log_std), got 2.0" in error_of(
        ["--method", "match", "--initial-log-std", "2", "--out", str(tmp_path / "a")])
    assert "--resume continues the run as its config.json defines it; --learning-rate cannot change it" in error_of(
        ["--resume", "--learning-rate", "1e-3", "--out", str(tmp_path / "a")])
    (tmp_path / "empty").mkdir()
    assert train_cli.main(["--resume", "--out", str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a run directory" in err[0]
    with pytest.raises(RunError, match="no checkpoint"):
        (tmp_path / "nockpt").mkdir()
        (tmp_path / "nockpt" / "config.json").write_text(RunSpec(ppo=get_preset("tiny")).to_json())
        train(None, tmp_path / "nockpt", resume=True)


def test_cli_usage_errors_end_with_the_error_after_a_one_line_usage(tmp_path, capsys):
    """A usage error prints one short usage line pointing to --help, then the error: not the usage of
    every option."""
    with pytest.raises(SystemExit) as exit_info:
        train_cli.parse_args(["--method", "sac", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("usage: train.py --method {pose,vices,hybrid,match} --out DIR") \
        and lines[0].endswith("(see --help)")
    assert lines[1].startswith("train.py: error: argument --method: invalid choice: 'sac'")


def test_train_cli_checks_out_before_building_anything(tmp_path, monkeypatch, capsys):
    """--out holding a run (say --resume), a file on the way, a place that takes no files: one line in
    the command line's words, before the spec is built (nothing compiled). train() says the same in
    Python's words."""
    def no_work(args):
        raise AssertionError("work began before --out was checked")

    monkeypatch.setattr(train_cli, "build_spec", no_work)
    held = tmp_path / "held"
    checkpoints.save(checkpoints.latest_dir(held), 1, {"x": np.zeros(2, np.float32)})
    (tmp_path / "afile").write_text("")
    cases = [(held, f"error: --out {held} already holds a run: add --resume to continue it, or choose another --out"),
             (tmp_path / "afile" / "run", f"run directory: {tmp_path / 'afile'} is a file, not a directory")]
    if pathlib.Path("/proc/self").exists():
        cases.append((pathlib.Path("/proc/x"), "error: --out /proc/x cannot be a run directory: cannot create files"))
    for out, message in cases:
        assert train_cli.main(["--method", "match", "--preset", "tiny", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert train_cli.main(["--method", "match", "--out", str(tmp_path / "new"), "--tensorboard",
                           str(tmp_path / "afile" / "tb")]) == 2
    assert capsys.readouterr().err.strip() == (f"error: --tensorboard {tmp_path / 'afile' / 'tb'}: "
                                               f"{tmp_path / 'afile'} is a file, not a directory")
    monkeypatch.setattr(training, "Run", no_work)
    with pytest.raises(RunError, match=r"already holds a run: continue it with resume=True") as held_error:
        train(TINY_2_SEEDS, held)
    assert "--resume" not in str(held_error.value)
    with pytest.raises(RunError, match=r"cannot write the run directory .*afile/run: .*afile is a file, not a dir"):
        train(TINY_2_SEEDS, tmp_path / "afile" / "run")


def test_train_cli_tensorboard_equals_metrics_csv_across_a_resume(tmp_path):
    """Tiny MATCH run, 2 seeds (the runner test's programs), one chunk, then --resume for another: the
    event files' scalars are metrics.csv's values, per seed and as the mean over seeds."""
    pytest.importorskip("tensorboardX")
    import csv

    from tb_events import read_scalars

    out = tmp_path / "run"
    common = ["--no-progress", "--max-chunks", "1", "--out", str(out), "--tensorboard"]
    assert train_cli.main(["--method", "match", "--preset", "tiny", "--seeds", "2", "--total-steps", "128"]
                          + common) == 0
    assert train_cli.main(["--resume"] + common) == 0
    with (out / "metrics.csv").open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == 4  # 2 iterations x 2 seeds
    scalars = read_scalars(out / "tensorboard")
    steps = sorted({int(r["env_steps"]) for r in table})
    assert steps == [32, 64]
    for key in ("loss", "value_loss", "p_force_free", "learning_rate", "episodes", "success_rate"):
        logged = [r for r in table if r[key] != ""]  # no success rate in an iteration where no episode ended
        for seed in (0, 1):
            expected = {int(r["env_steps"]): float(r[key]) for r in logged if r["seed_index"] == str(seed)}
            assert scalars.get(f"seed{seed}/{key}", {}) == pytest.approx(expected, rel=1e-6), key
        mean = {s: np.mean([float(r[key]) for r in logged if int(r["env_steps"]) == s])
                for s in {int(r["env_steps"]) for r in logged}}
        assert scalars.get(f"mean/{key}", {}) == pytest.approx(mean, rel=1e-6), key
    assert len(scalars["seed0/loss"]) == 2
    assert not any(tag.endswith(("/iteration", "/env_steps", "/seed", "/wall_clock_s")) for tag in scalars)
    custom = tmp_path / "tb"
    assert train_cli.main(["--resume", "--no-progress", "--max-chunks", "1", "--out", str(out),
                           "--tensorboard", str(custom)]) == 0
    assert set(read_scalars(custom)["seed1/loss"]) == {96}


def test_corrupted_checkpoint_is_a_clear_error(tmp_path, capsys):
    tree = {"a": np.arange(6.0, dtype=np.float32).reshape(2, 3), "b": np.ones(4, np.int32)}
    checkpoints.save(tmp_path / "ck", 5, tree)
    restored = checkpoints.restore(tmp_path / "ck", tree)
    assert _leaves_equal(restored, tree)
    for path in (tmp_path / "ck" / "5").rglob("*"):
        if path.is_file() and path.stat().st_size > 0 and "METADATA" not in path.name:
            path.write_bytes(b"\x00garbage" * 3)
    with pytest.raises(checkpoints.CheckpointError) as err:
        checkpoints.restore(tmp_path / "ck", tree)
    message = str(err.value)
    assert "unreadable" in message and "\n" not in message
    with pytest.raises(checkpoints.CheckpointError, match="no checkpoint found"):
        checkpoints.restore(tmp_path / "none", tree)


def test_a_damaged_checkpoint_is_one_line_without_event_loop_tracebacks(tmp_path, monkeypatch):
    """Truncated data files fail the restore while other reads are in flight; their "Event loop is
    closed" reports (printed after the error, at random) are dropped, other unraisable reports are not."""
    reported = []
    monkeypatch.setattr(sys, "unraisablehook", reported.append)
    tree = {f"x{i}": np.arange(2000.0 + i, dtype=np.float32) for i in range(8)}
    checkpoints.save(tmp_path / "ck", 1, tree)
    for path in (tmp_path / "ck" / "1").rglob("*"):
        if path.is_file() and path.parent.name == "d":
            path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    for _ in range(5):
        with pytest.raises(checkpoints.CheckpointError, match="unreadable"):
            checkpoints.restore(tmp_path / "ck", tree)
    time.sleep(0.5)  # the reads still in flight complete
    assert [str(r.exc_value) for r in reported] == []
    other = RuntimeError("something else")
    sys.unraisablehook(type("Unraisable", (), dict(exc_type=RuntimeError, exc_value=other, exc_traceback=None,
                                                    err_msg=None, object=None))())
    assert [r.exc_value for r in reported] == [other]


@pytest.mark.slow
def test_envs_shard_over_host_devices(tmp_path):
    """In a fresh process with 3 CPU devices, 4 envs split over 2 of them (the most that divide 4);
    for 2 seeds (one seed takes the same path with a seed axis of 1) the env step runs under shard_map, the rollout matches an unsharded trainer's
    from the same state, and the second chunk reuses the first one's compilation (same shardings).
    The rollout's step has no cross-device collective (each would make the devices wait for each
    other at every env step); the compiled chunk comes back from the persistent cache for the check."""
    code = (
        "import re, match_jax, jax, numpy as np\n"
        f"jax.config.update('jax_compilation_cache_dir', {str(tmp_path / 'jit_cache')!r})\n"
        "jax.config.update('jax_persistent_cache_min_compile_time_secs', 0.0)\n"
        "COLLECTIVE = r' (all-reduce|all-gather|all-to-all|collective-permute|reduce-scatter)(-start)?\\('\n"
        "from match_jax.rl.ppo import make_trainer\n"
        "from match_jax.training.presets import get_preset\n"
        "from match_jax.training.runs import RunSpec, Run, batch_mesh, shard_envs\n"
        "assert len(jax.devices()) == 3\n"
        "assert batch_mesh(4).size == 2 and batch_mesh(3).size == 3 and batch_mesh(5) is None\n"
        "for seeds in (2,):\n"
        f"    run = Run(RunSpec(ppo=get_preset('tiny', method='match'), num_seeds=seeds), {str(tmp_path)!r})\n"
        "    start = run.initial_state()\n"
        "    ref_state, ref = jax.jit(make_trainer(run.spec.ppo, run.env).train_chunk)(start)\n"
        "    state = shard_envs(start)\n"
        "    leaf = state.env_state.obs['state']\n"
        "    assert len(leaf.sharding.device_set) == 2 and leaf.sharding.spec[1] == 'envs', leaf.sharding\n"
        "    state, m = run.chunk(state)\n"
        "    hlo = run.programs.chunk.lower(state, run.values).compile().as_text()\n"
        "    synced = [l for l in hlo.splitlines() if 'rollout_step' in l and re.search(COLLECTIVE, l)]\n"
        "    assert not synced, synced[0][:300]\n"
        "    for key in ('mean_reward', 'contact_fraction', 'episodes'):\n"
        "        np.testing.assert_allclose(m[key], ref[key], rtol=1e-4, atol=1e-6, err_msg=key)\n"
        "    np.testing.assert_allclose(state.env_state.obs['state'], ref_state.env_state.obs['state'], atol=1e-4)\n"
        "    state, m = run.chunk(state)\n"
        "    assert run.programs.chunk._cache_size() == 1, (seeds, run.programs.chunk._cache_size())\n"
        "    assert np.all(np.isfinite(np.asarray(m['loss'])))\n"
        "print('ok', len(state.env_state.obs['state'].sharding.device_set))\n"
    )
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=3", PYTHONPATH=str(REPO))
    env.pop("JAX_NUM_CPU_DEVICES", None)
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=900)
    except subprocess.TimeoutExpired:
        pytest.fail("the 3-device subprocess did not finish within 900 s: a hang, or cores busy with other work")
    assert out.returncode == 0, out.stderr[-3000:]
    assert "ok 2" in out.stdout


@pytest.mark.slow
def test_several_seeds_initialise_without_deadlock():
    """cpu preset, 3 seeds: the initial state must become ready. A vmap over seeds made the orthogonal
    initialisers one batched LAPACK QR, which deadlocked XLA's CPU thread pool in most tries."""
    code = ("import match_jax, jax\n"
            "from match_jax.rl.ppo import make_trainer\nfrom match_jax.training.runs import make_env\n"
            "from match_jax.training.presets import get_preset\n"
            "ppo = get_preset('cpu', method='match')\n"
            "trainer = make_trainer(ppo, make_env(ppo))\n"
            "state = jax.jit(trainer.init)(jax.random.split(jax.random.PRNGKey(0), 3))\n"
            "jax.block_until_ready(state)\n"
            "print('ready', state.env_state.obs['state'].shape)\n")
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=240)
    except subprocess.TimeoutExpired:
        pytest.fail("initialising 3 seeds did not finish in 240 s (the batched-QR deadlock)")
    assert out.returncode == 0, out.stderr[-3000:]
    assert "ready (3, 128," in out.stdout


@pytest.mark.parametrize("setting, expected", [(None, "cores"), ("1", 1)])
def test_import_gives_one_cpu_device_per_core_unless_set(setting, expected):
    """`import match_jax` makes one JAX CPU device per usable core; JAX_NUM_CPU_DEVICES wins."""
    code = ("import match_jax, jax\nfrom match_jax._xla import usable_cores\n"
            "print(len(jax.devices()), usable_cores())\n")
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_NUM_CPU_DEVICES", "XLA_FLAGS")}
    if setting is not None:
        env["JAX_NUM_CPU_DEVICES"] = setting
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    devices, cores = (int(v) for v in out.stdout.split()[-2:])
    assert devices == (cores if expected == "cores" else expected)


def test_read_metrics_leaves_out_a_line_being_written_and_names_a_damaged_one(tmp_path):
    rows = [{"iteration": 1, "seed_index": 0}, {"iteration": 2, "seed_index": 0}]
    complete = "".join(json.dumps(r) + "\n" for r in rows)
    (tmp_path / "metrics.jsonl").write_text(complete + '{"iteration": 3, "seed_')  # an append in progress
    assert read_metrics(tmp_path) == rows
    (tmp_path / "metrics.jsonl").write_text('{"iteration": 1\n' + complete)
    with pytest.raises(RunError, match=r"metrics.jsonl line 1 is not a JSON row"):
        read_metrics(tmp_path)
    assert read_metrics(tmp_path / "missing") == []


def test_checkpoint_writer_runs_one_write_at_a_time_and_reraises():
    events = []
    release = threading.Event()

    def slow_write(name):
        release.wait(5)
        events.append(name)

    def failing_write():
        raise OSError("disk full")

    writer = _CheckpointWriter()
    writer.submit(slow_write, "first")
    assert events == []  # the write runs in the background
    release.set()
    writer.submit(failing_write)  # waits for "first" before starting the next write
    assert events == ["first"]
    with pytest.raises(OSError, match="disk full"):
        writer.wait()
    writer.close()


def test_train_cli_controller_and_force_law_flags(tmp_path):
    """Default: the authors' task (Factory's law, the literal force law, wrist sensor, peg offset, 15 Hz
    break); the paper's M_x law, the damped force law and each task setting are one flag each, and
    --task earlier is this project's earlier variant."""
    spec = train_cli.build_spec(train_cli.parse_args(["--method", "match", "--out", str(tmp_path)]))
    c = spec.env.controller
    assert not c.use_task_inertia and not c.force_feedforward and c.force_damping == (0.0, 0.0, 0.0)
    assert spec.env == dataclasses.replace(FPiHConfig(control="hybrid"), controller=c)
    spec = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--controller", "paper", "--force-law", "damped", "--out", str(tmp_path)]))
    c = spec.env.controller
    assert c.use_task_inertia and c.force_feedforward and c.force_damping == (20.0, 20.0, 20.0)
    assert spec.env.break_sampling == "policy_step"
    earlier = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--task", "earlier", "--hole-noise-mm", "2.5", "--out", str(tmp_path)])).env
    assert earlier.break_sampling == "peak" and earlier.force_sensor == "peg_contact" and not earlier.observe_torque
    assert not earlier.randomization.enabled and earlier.spawn_noise_type == "gaussian"
    assert earlier.controller.force_feedforward and earlier.hole_obs_noise == 0.0025
    # the authors' randomised runs: the authors' task plus their dynamics draws, 0.5 mm EE noise, no torque
    randomised = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--task", "authors_dr", "--out", str(tmp_path)])).env
    assert randomised.randomization.dynamics and randomised.randomization.rot_stiffness == (20.0, 60.0)
    assert randomised.ee_pos_obs_noise == 0.0005 and not randomised.observe_torque
    assert dataclasses.replace(randomised, randomization=spec.env.randomization, ee_pos_obs_noise=0.00025,
                               observe_torque=True, controller=c) == dataclasses.replace(spec.env, controller=c)
    rigid = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--task", "authors_dr", "--peg-offset-mm", "0,0,0", "--out", str(tmp_path)])).env
    assert rigid.randomization == dataclasses.replace(randomised.randomization, peg_offset_range=(0.0, 0.0, 0.0))
    assert set(train_cli.TASKS) == set(TASKS)  # train.py's --task choices (listed before jax loads) are the tasks
    mixed = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--peg-offset-mm", "1,0,2", "--force-frame", "hand", "--force-sensor", "peg_contact",
         "--out", str(tmp_path)])).env
    assert mixed.randomization.peg_offset_range == (0.001, 0.0, 0.002) and mixed.force_frame == "hand"
    assert mixed.force_sensor == "peg_contact" and not mixed.observe_torque
    with pytest.raises(SystemExit):
        train_cli.parse_args(["--method", "match", "--peg-offset-mm", "1,2", "--out", str(tmp_path)])
    spec = train_cli.build_spec(train_cli.parse_args(
        ["--method", "pose", "--break-sampling", "policy_step", "--out", str(tmp_path)]))
    assert spec.env.break_sampling == "policy_step"


def test_train_cli_network_flags(tmp_path, capsys):
    """--actor-hidden/--actor-blocks/--critic-hidden/--critic-blocks/--initial-p-position/--initial-force-z replace those
    fields of the preset's network only; a bad value is a one-line error naming it."""
    preset = train_cli.build_spec(train_cli.parse_args(["--method", "match", "--out", str(tmp_path)])).ppo.network
    spec = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--actor-hidden", "256", "--critic-blocks", "3", "--initial-p-position", "0.99",
         "--initial-force-z", "0", "--out", str(tmp_path)]))
    assert spec.ppo.network == dataclasses.replace(preset, actor_hidden=256, critic_blocks=3, initial_p_position=0.99,
                                                   initial_force_z=0.0)
    decaying = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--learning-rate", "1e-3", "--learning-rate-end", "1e-4", "--out", str(tmp_path)])).ppo
    assert (decaying.learning_rate, decaying.learning_rate_end, decaying.network) == (1e-3, 1e-4, preset)
    discounted = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--gamma", "0.99", "--gae-lambda", "0.9", "--out", str(tmp_path)])).ppo
    assert (discounted.gamma, discounted.gae_lambda, discounted.network) == (0.99, 0.9, preset)
    adaptive = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--learning-rate", "1e-3", "--desired-kl", "0.01", "--out", str(tmp_path)])).ppo
    assert (adaptive.learning_rate, adaptive.desired_kl, adaptive.learning_rate_end) == (1e-3, 0.01, None)
    for flag, value, message in (("--critic-hidden", "0", "critic_hidden must be an integer >= 1, got 0"),
                                 ("--actor-blocks", "-1", "actor_blocks must be an integer >= 0, got -1"),
                                 ("--initial-p-position", "1", "initial_p_position must be in (0, 1), got 1.0"),
                                 ("--initial-force-z", "5", "--initial-force-z must be in [-20, 0] N"),
                                 ("--gamma", "1.5", "gamma must be in [0, 1], got 1.5"),
                                 ("--gae-lambda", "-0.1", "gae_lambda must be in [0, 1], got -0.1"),
                                 ("--desired-kl", "nan", "desired_kl must be a finite number > 0 or None, got nan"),
                                 ("--actor-hidden", "x", "--ppo.network.actor-hidden: invalid literal for int()")):
        with pytest.raises(SystemExit):
            train_cli.parse_args(["--method", "match", flag, value, "--out", str(tmp_path)])
        assert message in capsys.readouterr().err.strip().splitlines()[-1]


def test_train_cli_contact_timeconst_and_set(tmp_path, capsys):
    """--contact-timeconst sets the task's peg-contact solref time constant (default the task's 0.02 s);
    --set replaces learning settings by name after the other flags; bad values end in one line each,
    before anything is built."""
    default = train_cli.build_spec(train_cli.parse_args(["--method", "match", "--out", str(tmp_path)]))
    assert default.env.contact_timeconst == 0.02
    soft = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--contact-timeconst", "0.05", "--out", str(tmp_path)]))
    assert soft.env == dataclasses.replace(default.env, contact_timeconst=0.05)
    spec = train_cli.build_spec(train_cli.parse_args(
        ["--method", "match", "--learning-rate", "1e-5", "--set", "critic_steps=2", "value_loss=huber",
         "--set", "network.head_scale=0.14", "--out", str(tmp_path)]))
    assert (spec.ppo.learning_rate, spec.ppo.critic_steps, spec.ppo.value_loss) == (1e-5, 2, "huber")
    assert spec.ppo.network == dataclasses.replace(default.ppo.network, head_scale=0.14)
    for argv, message in ((["--contact-timeconst", "0"], "contact_timeconst must be a finite number > 0 s, got 0.0"),
                          (["--set", "critic_steps=x"], "--ppo.critic-steps: invalid literal for int()"),
                          (["--set", "kl_threshold=-1"], "kl_threshold must be a finite number > 0 or None"),
                          (["--set", "critic_steps"], "--set expects FIELD=VALUE, got 'critic_steps'"),
                          (["--ppo.learning-rat", "1"], "(did you mean --ppo.actor-learning-rate,"),
                          (["--env.break-sampling", "x"], "break_sampling must be one of ('peak', 'policy_step')")):
        with pytest.raises(SystemExit):
            train_cli.parse_args(["--method", "match", *argv, "--out", str(tmp_path)])
        assert message in capsys.readouterr().err.strip().splitlines()[-1]
