"""The config-field flags: every field of the learning and task configs is a flag that tyro derives
(`--ppo.FIELD`, `--env.controller.FIELD`, ...), train.py's short names and --set are the same flags,
and a bad flag or value is one line."""

import dataclasses
import math
import pathlib
import typing

import pytest

import train as train_cli
from match_jax.cli import FieldError, field_flag, fields_help, parse_fields, rewrite_short_names, set_assignments
from match_jax.envs.tasks import task_config
from match_jax.training.presets import get_preset


def _defaults():
    ppo = get_preset("cpu", method="match")
    return {"ppo": ppo, "env": task_config("authors", ppo.control)}


def _leaves(config, prefix):
    """(field path, value) of every non-dataclass field of `config`, nested configs walked."""
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if dataclasses.is_dataclass(value):
            yield from _leaves(value, f"{prefix}.{field.name}")
        else:
            yield f"{prefix}.{field.name}", value


def _tokens(value):
    if value is None:
        return ["None"]
    if isinstance(value, tuple):
        return [str(x) for v in value for x in _tokens(v)]
    return [str(value)]


def _changed(value, hint):
    """A valid value of type `hint` other than `value` (halved numbers, doubled counts, flipped booleans), or
    None for strings (their choices are tested one by one below)."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if value is None:
        if typing.get_origin(args[0]) is tuple:
            return (0.9, 1.1)
        return args[0](2) if args[0] is int else 0.5
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return 2 * value if value else 1
    if isinstance(value, float):
        return 5.0 if math.isinf(value) else 0.5 * value if value else 0.001
    if isinstance(value, tuple):
        return tuple(_changed(v, type(v)) for v in value)
    return None


def test_every_config_field_is_a_flag_that_sets_it():
    """Every field's flag at once, each with another value than its default: each value lands in its own
    field (a flag read and dropped, or written to another field, fails here), and the help lists each flag."""
    defaults = _defaults()
    tokens, expected = [], {}
    for group, config in defaults.items():
        for path, value in _leaves(config, group):
            owner = config
            for name in path.split(".")[1:-1]:
                owner = getattr(owner, name)
            new = _changed(value, typing.get_type_hints(type(owner))[path.rpartition(".")[2]])
            if new is not None:
                tokens += [field_flag(path), *_tokens(new)]
                expected[path] = new
    assert len(expected) > 80  # PPOConfig, NetworkConfig, FPiHConfig, ControllerConfig, ActionConfig, ...
    # desired_kl is a second step-size schedule, which learning_rate_end excludes: it gets its own call
    alone = tokens.index(field_flag("ppo.desired_kl"))
    calls = [tokens[:alone] + tokens[alone + 2:], tokens[alone:alone + 2]]
    got = {}
    for call in calls:
        parsed = parse_fields(defaults, call, "train.py")
        got.update({path: value for group, config in parsed.items() for path, value in _leaves(config, group)
                    if path in expected and field_flag(path) in call})
    wrong = {path: (got.get(path), new) for path, new in expected.items() if got.get(path) != new}
    assert not wrong, wrong
    help_text = fields_help(defaults, "train.py")
    missing = [path for group, config in defaults.items() for path, _ in _leaves(config, group)
               if field_flag(path) + " " not in help_text]
    assert not missing, missing
    assert "usage: train.py [-h] [OPTIONS]" not in help_text  # tyro's own usage line is left out


def test_field_flags_replace_exactly_their_fields_nested_tuples_and_none_included():
    defaults = _defaults()
    ppo, env = defaults["ppo"], defaults["env"]
    parsed = parse_fields(defaults, [
        "--ppo.network.head-scale", "0.2", "--ppo.kl-threshold", "0.05", "--ppo.normalize-returns", "true",
        "--env.controller.force-gain", "0.3", "--env.randomization.peg-mass-scale", "0.8", "1.2",
        "--env.spawn-noise", "0.01", "0.01", "0.005", "--env.reward-terms", "5", "4", "50", "2",
        "--env.break-force", "inf", "--ppo.network.initial-force-z", "none"], "train.py")
    assert parsed["ppo"] == dataclasses.replace(
        ppo, kl_threshold=0.05, normalize_returns=True,
        network=dataclasses.replace(ppo.network, head_scale=0.2, initial_force_z=None))
    assert parsed["env"] == dataclasses.replace(
        env, controller=dataclasses.replace(env.controller, force_gain=0.3),
        randomization=dataclasses.replace(env.randomization, peg_mass_scale=(0.8, 1.2)),
        spawn_noise=(0.01, 0.01, 0.005), reward_terms=((5.0, 4.0), (50.0, 2.0)), break_force=float("inf"))


def test_short_names_and_set_are_the_field_flags():
    paths = {path for name, config in _defaults().items() for path, _ in _leaves(config, name)}
    assert set(train_cli.SHORT_NAMES.values()) <= paths
    assert rewrite_short_names(["--learning-rate=1e-5", "--gamma", "0.9", "--out", "x"], train_cli.SHORT_NAMES) == [
        "--ppo.learning-rate", "1e-5", "--ppo.gamma", "0.9", "--out", "x"]
    assert set_assignments(["critic_steps=2", "network.head_scale=0.14", "adam_eps=1e-8"], "ppo") == [
        "--ppo.critic-steps", "2", "--ppo.network.head-scale", "0.14", "--ppo.adam-eps", "1e-8"]
    short = train_cli.parse_args(["--method", "match", "--learning-rate", "1e-5", "--critic-blocks", "3",
                                  "--break-force", "inf", "--spawn-noise", "gaussian", "--out", "x"])
    full = train_cli.parse_args(["--method", "match", "--ppo.learning-rate", "1e-5", "--ppo.network.critic-blocks", "3",
                                 "--env.break-force", "inf", "--env.spawn-noise-type", "gaussian", "--out", "x"])
    assert (short.ppo, short.env) == (full.ppo, full.env)
    assert full.ppo.learning_rate == 1e-5 and full.env.spawn_noise_type == "gaussian"


def test_set_assignments_parse_by_field_type():
    defaults = _defaults()
    base = defaults["ppo"]
    cfg = parse_fields(defaults, set_assignments(
        ["critic_steps=2", "value_loss=huber", "kl_threshold=0.05", "normalize_returns=true", "network.head_scale=0.14",
         "network.initial_force_z=none", "critic_learning_rate=1e-5"], "ppo"), "train.py")["ppo"]
    assert (cfg.critic_steps, cfg.value_loss, cfg.kl_threshold, cfg.normalize_returns) == (2, "huber", 0.05, True)
    assert (cfg.network.head_scale, cfg.network.initial_force_z, cfg.critic_lr) == (0.14, None, 1e-5)
    assert cfg.network.actor_hidden == base.network.actor_hidden  # the rest of the preset stays
    for bad, match in [("critic_steps=two", "--ppo.critic-steps: invalid literal for int"),
                       ("nope=1", "Unrecognized options: --ppo.nope"), ("critic_steps", "FIELD=VALUE"),
                       ("critic_steps=0", "critic_steps must be a positive"), ("value_loss=l1", "value_loss must be"),
                       ("normalize_returns=maybe", "invalid choice 'maybe'"), ("network=1", "Unrecognized options")]:
        with pytest.raises(FieldError, match=match) as error:
            parse_fields(defaults, set_assignments([bad], "ppo"), "train.py")
        assert "\n" not in str(error.value)


def test_suite_config_flags_apply_to_every_run_after_its_own_settings(tmp_path, capsys):
    from match_jax.experiments.pipeline import parse_args
    from match_jax.experiments.suite import run_spec

    cfg = parse_args(["--out", str(tmp_path), "--learning-rate", "1e-3", "--initial-force-z", "-1",
                      "--env.contact-timeconst", "0.05", "--ppo.network.critic-blocks", "3"])
    plain = parse_args(["--out", str(tmp_path)])
    for name in ("pose", "match_nossl", "pose_unbreakable"):
        spec, base = run_spec(name, cfg), run_spec(name, plain)
        assert spec.ppo == dataclasses.replace(base.ppo, learning_rate=1e-3, network=dataclasses.replace(
            base.ppo.network, initial_force_z=-1.0, critic_blocks=3)), name
        assert spec.env == dataclasses.replace(base.env, contact_timeconst=0.05), name  # break force, noise: the run's
    for argv, message in ((["--gamma", "2"], "gamma must be in [0, 1], got 2.0"),
                          (["--ppo.method", "pose"], "--ppo.method: the suite sets it per run"),
                          (["--nope"], "Unrecognized options: --nope")):
        with pytest.raises(SystemExit):
            parse_args(["--out", str(tmp_path), *argv])
        assert message in capsys.readouterr().err.strip().splitlines()[-1]


SHIPPED_RUN = pathlib.Path(__file__).resolve().parents[1] / "results" / "suite_authors" / "runs" / "pose"


def test_eval_env_flags_replace_the_runs_task_config_before_any_work(monkeypatch, capsys):
    import eval as eval_cli
    from match_jax.training import evaluation
    from match_jax.training.runs import load_spec

    run_env = load_spec(SHIPPED_RUN).env
    args = eval_cli.parse_args(["--env.contact-timeconst", "0.05", str(SHIPPED_RUN), "--env.controller.force-gain",
                                "0.3", "--episodes", "2"])
    assert (args.run_dir, args.episodes) == (SHIPPED_RUN, 2)
    assert args.env_config == dataclasses.replace(run_env, contact_timeconst=0.05,
                                                  controller=dataclasses.replace(run_env.controller, force_gain=0.3))
    assert eval_cli.parse_args([str(SHIPPED_RUN)]).env_config is None

    class Evaluated(Exception):
        pass

    def grid_rollout(ppo, env_config, mean_action="tanh"):  # the evaluation's env, caught before compiling
        raise Evaluated(env_config, mean_action)

    monkeypatch.setattr(evaluation, "_grid_rollout", grid_rollout)
    with pytest.raises(Evaluated) as evaluated:
        evaluation.evaluate_run_grid(SHIPPED_RUN, 2, env_config=args.env_config)
    assert evaluated.value.args[0].contact_timeconst == 0.05
    with pytest.raises(Evaluated) as evaluated:  # the authors' deterministic action reaches the rollout
        evaluation.evaluate_run_grid(SHIPPED_RUN, 2, mean_action="pre_tanh")
    assert evaluated.value.args[1] == "pre_tanh"
    with pytest.raises(ValueError, match="mean_action must be one of"):
        evaluation.evaluate_run_grid(SHIPPED_RUN, 2, mean_action="raw")
    assert eval_cli.parse_args([str(SHIPPED_RUN), "--mean-action", "pre_tanh"]).mean_action == "pre_tanh"
    monkeypatch.undo()
    spec = load_spec(SHIPPED_RUN)  # the pre-tanh rollout's env passes actions unclipped; nothing compiles yet
    assert evaluation._grid_rollout(spec.ppo, spec.env, "pre_tanh")[0].config.actions.clip is False
    assert evaluation._grid_rollout(spec.ppo, spec.env, "tanh")[0].config.actions.clip is True
    with pytest.raises(ValueError, match="the run's policies need control='pose'"):
        evaluation.evaluate_run_grid(SHIPPED_RUN, 2, env_config=dataclasses.replace(run_env, control="hybrid"))
    for argv, message in (([str(SHIPPED_RUN), "--env.contact-timeconst", "x"],
                           "--env.contact-timeconst: could not convert string to float: 'x'"),
                          (["--baseline", "spiral", "--env.break-force", "5"], "not with --baseline"),
                          ([str(SHIPPED_RUN), "--env.control", "hybrid"], "--env.control and --env.observe-torque"),
                          (["--baseline", "spiral", "--mean-action", "pre_tanh"], "not to --baseline")):
        with pytest.raises(SystemExit):
            eval_cli.parse_args(argv)
        assert message in capsys.readouterr().err.strip().splitlines()[-1]


def test_field_flags_apply_after_the_flags_that_build_the_defaults(tmp_path, capsys):
    args = train_cli.parse_args(["--method", "match", "--controller", "paper", "--env.controller.use-task-inertia",
                                 "false", "--hole-noise-mm", "2", "--env.hole-obs-noise=0.003", "--peg-offset-mm",
                                 "1,0,1", "--env.randomization.peg-offset-range", "0", "0", "0.002",
                                 "--ppo.normalize-returns=TRUE", "--out", str(tmp_path)])
    assert not args.env.controller.use_task_inertia and args.env.hole_obs_noise == 0.003
    assert args.env.randomization.peg_offset_range == (0.0, 0.0, 0.002) and args.ppo.normalize_returns
    for argv, message in ((["--method", "match", "--no-ssl", "--ssl-coef", "0.5"], "--no-ssl sets the selection"),
                          (["--resume", "--ppo.gamma", "0.9"], "--ppo.gamma cannot change it"),
                          (["--help", "--hole-noise-mm", "-1"], "--hole-noise-mm must be a finite number >= 0")):
        with pytest.raises(SystemExit):
            train_cli.parse_args([*argv, "--out", str(tmp_path)])
        assert message in capsys.readouterr().err.strip().splitlines()[-1]


def test_train_help_lists_the_run_flags_the_short_names_and_every_field_flag(capsys):
    with pytest.raises(SystemExit) as exit_info:
        train_cli.parse_args(["--help", "--preset", "authors"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for text in ("--method", "--resume", "--learning-rate = --ppo.learning-rate", "--ppo.network.actor-hidden INT",
                 "--env.controller.force-gain FLOAT", "Adam epsilon (default: 1e-08)"):  # the authors preset's
        assert text in out, text


def test_suite_refuses_the_fields_that_tell_its_runs_apart_and_checks_smoke_sizes(tmp_path, capsys):
    from match_jax.experiments.pipeline import parse_args

    for argv, message in ((["--ppo.ssl-coef", "0.3"], "--ppo.ssl-coef: the suite sets it per run"),
                          (["--break-force", "20"], "--env.break-force: the suite sets it per run"),
                          (["--smoke", "--minibatches", "3"], "must divide into minibatches (3)")):
        with pytest.raises(SystemExit):
            parse_args(["--out", str(tmp_path), *argv])
        assert message in capsys.readouterr().err.strip().splitlines()[-1]


def test_eval_takes_a_run_dir_after_tuple_valued_env_flags():
    import eval as eval_cli

    args = eval_cli.parse_args(["--env.spawn-noise", "0.01", "0.01", "0.005", str(SHIPPED_RUN),
                                "--env.randomization.peg-friction", "0.5", "2", "--episodes", "2"])
    assert args.run_dir == SHIPPED_RUN and args.episodes == 2
    assert args.env_config.spawn_noise == (0.01, 0.01, 0.005)
    assert args.env_config.randomization.peg_friction == (0.5, 2.0)
