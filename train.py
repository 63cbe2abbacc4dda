"""Train a fragile peg-in-hole policy with PPO: Pose, VICES, Hybrid-Basic or MATCH.

    python train.py --method match --preset cpu --out runs/match_cpu
    python train.py --method pose --preset cpu --seeds 3 --total-steps 2000000 --out runs/pose_cpu
    python train.py --method match --no-ssl --preset paper --seeds 5 --out runs/match_nossl
    python train.py --resume --out runs/match_cpu          # continue an interrupted run
    python train.py --resume --total-steps 8000000 --out runs/match_cpu   # train a finished run further

Ctrl-C (or SIGTERM) stops a run once the running chunk is done and saved; --resume continues it.
All seeds train in one XLA program. The run directory gets config.json, metrics.jsonl/.csv (one row
per iteration and seed: success and break rate of the episodes that ended, losses, ...) and orbax
checkpoints (latest full state; best policy per seed by training success rate).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import pathlib
import sys

import match_jax  # noqa: F401  (sets the fast XLA CPU flag before JAX starts)

METHODS = ("pose", "vices", "hybrid", "match")
NETWORK_FIELDS = ("actor_hidden", "actor_blocks", "critic_hidden", "critic_blocks", "initial_log_std",
                  "initial_p_position", "initial_force_z")  # flags that replace a field of the preset's NetworkConfig
RESUME_FLAGS = ("resume", "out", "total_steps", "max_chunks", "time_budget_min", "no_progress",
                "tensorboard")  # apply with --resume


TASKS = ("authors", "earlier")  # match_jax.envs.tasks.TASKS
DYNAMICS = ("stable", "authors")  # match_jax.envs.randomization.DYNAMICS_PRESETS


def _three_floats(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}") from None
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}")
    return values


def parse_args(argv=None) -> argparse.Namespace:
    from match_jax.cli import Parser

    parser = Parser(prog="train.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                    short_usage="--method {pose,vices,hybrid,match} --out DIR [options] | --resume --out DIR")
    parser.add_argument("--method", choices=METHODS, help="pose | vices | hybrid (Hybrid-Basic) | match")
    parser.add_argument("--no-ssl", action="store_true", help="no supervised selection loss (beta = 0)")
    parser.add_argument("--ssl-coef", type=float, default=None,
                        help="beta of the selection loss, the weight of its mean over the 3 axes (default: 0.3 "
                             "for MATCH with the selection term in the ratio, else 1)")
    parser.add_argument("--ssl-after-update", action="store_true",
                        help="experimental: SSL-only steps after the PPO epochs instead of inside every PPO loss")
    parser.add_argument("--ssl-contact-only", action="store_true",
                        help="experimental: average the SSL over in-contact steps only (no SSL pull in free space)")
    parser.add_argument("--selection-not-in-ratio", action="store_true",
                        help="MATCH: leave the Bernoulli term out of the PPO ratio (authors' public code)")
    parser.add_argument("--preset", choices=["cpu", "authors", "paper", "tiny"], default="cpu",
                        help="sizes and learning settings (default cpu; authors: the authors' code's recipe, for GPUs)")
    parser.add_argument("--seeds", type=int, default=1, help="seeds trained together (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="base random seed")
    parser.add_argument("--total-steps", type=int, default=None, help="env steps per seed (preset default)")
    parser.add_argument("--num-envs", type=int, default=None, help="parallel envs per seed (preset default)")
    parser.add_argument("--rollout-steps", type=int, default=None,
                        help="env steps per env per PPO iteration (preset default)")
    parser.add_argument("--epochs", type=int, default=None, help="PPO epochs per iteration (preset default)")
    parser.add_argument("--minibatches", type=int, default=None, help="minibatches per epoch (preset default)")
    parser.add_argument("--iterations-per-chunk", type=int, default=None,
                        help="PPO iterations per jitted call, between logs and checkpoints (preset default)")
    parser.add_argument("--learning-rate", type=float, default=None,
                        help="Adam step size (default: the preset's, 1e-3 on cpu, 3e-4 on paper and tiny)")
    parser.add_argument("--learning-rate-end", type=float, default=None,
                        help="decay the step size linearly from --learning-rate to this value over the run's budget "
                             "(default: constant)")
    parser.add_argument("--desired-kl", type=float, default=None,
                        help="adapt the step size per minibatch to keep the approximate KL to the rollout policy near "
                             "this value, starting from --learning-rate (default: no adaptation)")
    parser.add_argument("--gamma", type=float, default=None,
                        help="discount per policy step (default: the preset's, 0.99 on cpu, 0.995 on paper and tiny)")
    parser.add_argument("--gae-lambda", type=float, default=None, help="GAE lambda (default 0.95)")
    parser.add_argument("--actor-hidden", type=int, default=None, help="actor SimBa width (preset default)")
    parser.add_argument("--actor-blocks", type=int, default=None, help="actor SimBa residual blocks (preset default)")
    parser.add_argument("--critic-hidden", type=int, default=None, help="critic SimBa width (preset default)")
    parser.add_argument("--critic-blocks", type=int, default=None, help="critic SimBa residual blocks (preset default)")
    parser.add_argument("--initial-log-std", type=float, default=None,
                        help="the actor's initial pre-tanh log std (default: the preset's, docs/training.md)")
    parser.add_argument("--initial-p-position", type=float, default=None,
                        help="hybrid methods: the untrained policy's probability of position control per axis "
                             "(default 0.93, as in the paper)")
    parser.add_argument("--initial-force-z", type=float, default=None,
                        help="hybrid methods: the force-z target (N, < 0 presses down) the untrained policy's mean "
                             "commands (default: the preset's, 0 on cpu, -1 on paper and tiny)")
    parser.add_argument("--set", nargs="+", action="extend", default=[], metavar="FIELD=VALUE",
                        help="set any learning setting of the preset by name, after the flags above: a PPOConfig "
                             "field (critic_steps=2, value_loss=huber, kl_threshold=0.05, ...) or network.FIELD "
                             "(network.head_scale=0.14); docs/training.md lists them")
    parser.add_argument("--hole-noise-mm", type=float, default=None,
                        help="hole-position observation noise during training, mm (default 1, gaussian)")
    parser.add_argument("--break-force", type=float, default=None,
                        help="break threshold, N (default 10; inf = unbreakable)")
    parser.add_argument("--contact-timeconst", type=float, default=None, metavar="S",
                        help="solref time constant of every peg contact, s (default 0.02, the task's; larger is "
                             "softer; docs/protocol.md#contact-stiffness-and-the-break-at-first-contact)")
    parser.add_argument("--task", choices=list(TASKS), default="authors",
                        help="task protocol: 'authors' (default: the authors' task, docs/protocol.md) or 'earlier' "
                             "(this project's earlier variant: rigid peg, peg contact force, peak break, damped "
                             "force law, gaussian spawn); the flags below override single settings")
    parser.add_argument("--break-sampling", choices=["peak", "policy_step"], default=None,
                        help="break on the force signal read once per policy step (the authors', default) or on "
                             "the peg's peak contact force over every physics step")
    parser.add_argument("--controller", choices=["paper", "factory"], default="factory",
                        help="task-space law: IsaacLab Factory's u = J^T F as the authors' code runs it (default; "
                             "k_p = 100 N/m at the end effector) or the paper's equation u = J^T M_x F "
                             "(k_p x task inertia: 240-630 N/m at the spawn pose)")
    parser.add_argument("--force-law", choices=["damped", "literal"], default=None,
                        help="force-controlled axes: the literal k_f (f_d - f), no feed-forward and no damping (the "
                             "authors', default) or k_f (f_d - f) + f_d - k_vf xdot")
    parser.add_argument("--force-sensor", choices=["wrist", "peg_contact"], default=None,
                        help="force signal of the law, the 15 Hz break and the observation: the wrist F/T sensor "
                             "(default) or the sum of the peg's contact forces (no torque observed)")
    parser.add_argument("--force-frame", choices=["world", "hand"], default=None,
                        help="frame of the force signal: world (default, the law's frame) or the hand frame fed "
                             "unrotated to the law and the policy (the authors' code)")
    parser.add_argument("--peg-offset-mm", type=_three_floats, default=None, metavar="X,Y,Z",
                        help="half-widths of the uniform peg offset in the hand, hand frame, mm (default 3,0,3; "
                             "0,0,0 = rigid)")
    parser.add_argument("--spawn-noise", choices=["uniform", "gaussian"], default=None,
                        help="hand spawn noise +-(2, 2, 1) cm uniform (default) or gaussian with those sds")
    parser.add_argument("--dynamics-randomization", nargs="?", const="stable", default=None,
                        choices=DYNAMICS,
                        help="draw per episode peg mass x U[0.8, 1.2], peg friction U[0.5, 2.0], k_p U[60, 140] N/m, "
                             "rotational k_p U[20, 30] N m/rad and force gain U[0.05, 0.6] ('stable', the default); "
                             "'authors' draws the rotational k_p from the authors' U[20, 60], where the arm oscillates "
                             "above ~34 (docs/transfer.md)")
    parser.add_argument("--arm-model-error", action="store_true",
                        help="draw per episode the robot's masses x U[0.99, 1.01] and rotor inertias x U[0.8, 1.25] "
                             "for the physics only; the control law keeps the nominal model (docs/transfer.md)")
    parser.add_argument("--physics-backend", choices=["jax", "warp"], default="jax",
                        help="MJX's JAX physics (default) or MuJoCo Warp (pip install 'match_jax[warp]'; "
                             "docs/gpu.md#physics-backend)")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="run directory")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its latest checkpoint")
    parser.add_argument("--max-chunks", type=int, default=None, help="stop after this many chunks (resumable)")
    parser.add_argument("--time-budget-min", type=float, default=None,
                        help="stop after the chunk that ends past this many minutes of wall clock (resumable)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--tensorboard", nargs="?", const=True, default=None, type=pathlib.Path, metavar="DIR",
                        help="also log the metrics as TensorBoard scalars to DIR (default: OUT/tensorboard); "
                             "needs tensorboardX (pip install 'match_jax[tensorboard]')")
    args = parser.parse_args(argv)
    if not args.resume and args.method is None:
        parser.error("--method is required (unless --resume)")
    if args.resume:  # the run's config.json defines it; only the budget and how this call runs may change
        ignored = [name for name, value in vars(args).items()
                   if name not in RESUME_FLAGS and value != parser.get_default(name)]
        if ignored:
            parser.error(f"--resume continues the run as its config.json defines it; --{ignored[0].replace('_', '-')} "
                         "cannot change it (only --total-steps, --max-chunks, --time-budget-min, --no-progress, "
                         "--tensorboard)")
    if args.physics_backend == "warp":
        from match_jax.envs import sim

        if not sim.warp_installed():
            parser.error(f"--physics-backend warp {sim.WARP_MISSING}")
    for name in ("seeds", "total_steps", "num_envs", "max_chunks", "rollout_steps", "epochs", "minibatches",
                 "iterations_per_chunk", "actor_hidden", "critic_hidden"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')} must be a positive integer, got {value}")
    for name in ("actor_blocks", "critic_blocks"):
        value = getattr(args, name)
        if value is not None and value < 0:
            parser.error(f"--{name.replace('_', '-')} must be an integer >= 0, got {value}")
    if args.time_budget_min is not None and not (args.time_budget_min > 0 and math.isfinite(args.time_budget_min)):
        parser.error(f"--time-budget-min must be a positive number of minutes, got {args.time_budget_min}")
    if args.hole_noise_mm is not None and not (args.hole_noise_mm >= 0 and math.isfinite(args.hole_noise_mm)):
        parser.error(f"--hole-noise-mm must be a finite number >= 0, got {args.hole_noise_mm}")
    if args.break_force is not None and not args.break_force > 0:
        parser.error(f"--break-force must be > 0 N, got {args.break_force}")
    if args.contact_timeconst is not None and not (args.contact_timeconst > 0 and math.isfinite(args.contact_timeconst)):
        parser.error(f"--contact-timeconst must be a finite number of seconds > 0, got {args.contact_timeconst}")
    if args.learning_rate is not None and not args.learning_rate > 0:
        parser.error(f"--learning-rate must be > 0, got {args.learning_rate}")
    end = args.learning_rate_end
    if end is not None and not (end >= 0 and math.isfinite(end)):
        parser.error(f"--learning-rate-end must be a finite number >= 0, got {args.learning_rate_end}")
    if args.desired_kl is not None:
        if not (args.desired_kl > 0 and math.isfinite(args.desired_kl)):
            parser.error(f"--desired-kl must be a finite number > 0, got {args.desired_kl}")
        if args.learning_rate_end is not None:
            parser.error(f"--desired-kl {args.desired_kl} and --learning-rate-end {args.learning_rate_end} are two "
                         "step-size schedules; choose one")
    for name in ("gamma", "gae_lambda"):
        value = getattr(args, name)
        if value is not None and not 0 <= value <= 1:
            parser.error(f"--{name.replace('_', '-')} must be in [0, 1], got {value}")
    if args.initial_log_std is not None:
        from match_jax.rl.networks import NetworkConfig
        low, high = NetworkConfig.min_log_std, NetworkConfig.max_log_std
        if not low < args.initial_log_std < high:
            parser.error(f"--initial-log-std must be in ({low:g}, {high:g}) (the actor's log-std bounds), "
                         f"got {args.initial_log_std}")
    if args.initial_p_position is not None and not 0 < args.initial_p_position < 1:
        parser.error(f"--initial-p-position must be in (0, 1), got {args.initial_p_position}")
    if args.initial_force_z is not None:
        from match_jax.envs.controllers.action_spaces import ActionConfig
        low, high = ActionConfig().force_z_range
        if not low <= args.initial_force_z <= high:
            parser.error(f"--initial-force-z must be in [{low:g}, {high:g}] N (the force-z action range), "
                         f"got {args.initial_force_z}")
    if args.ssl_coef is not None and not args.ssl_coef >= 0:
        parser.error(f"--ssl-coef must be >= 0, got {args.ssl_coef}")
    if args.set and args.method is not None:  # every assignment parses and the config accepts it, before any work
        try:
            _learner(args)
        except ValueError as err:
            parser.error(str(err))
    return args


def _learner(args: argparse.Namespace):
    """The PPOConfig the flags ask for: the preset, the flags that replace its fields, then --set."""
    from match_jax.training.overrides import apply_overrides
    from match_jax.training.presets import get_preset

    overrides = {"method": args.method}
    for name in ("total_steps", "num_envs", "learning_rate", "learning_rate_end", "desired_kl", "gamma", "gae_lambda",
                 "rollout_steps", "epochs", "minibatches", "iterations_per_chunk"):
        if getattr(args, name) is not None:
            overrides[name] = getattr(args, name)
    if args.no_ssl:
        overrides["ssl_coef"] = 0.0
    elif args.ssl_coef is not None:
        overrides["ssl_coef"] = args.ssl_coef
    if args.selection_not_in_ratio:
        overrides["selection_in_ratio"] = False
    if args.ssl_after_update:
        overrides["ssl_phase"] = "after"
    if args.ssl_contact_only:
        overrides["ssl_samples"] = "contact"
    ppo = get_preset(args.preset, **overrides)
    network = {name: getattr(args, name) for name in NETWORK_FIELDS if getattr(args, name) is not None}
    if network:
        ppo = dataclasses.replace(ppo, network=dataclasses.replace(ppo.network, **network))
    return apply_overrides(ppo, args.set)


def build_spec(args: argparse.Namespace):
    from match_jax.envs import FPiHConfig
    from match_jax.envs.tasks import task_config
    from match_jax.envs.randomization import DYNAMICS_PRESETS, ModelRandomization
    from match_jax.training.runs import RunSpec

    ppo = _learner(args)
    env = FPiHConfig(control=ppo.control)
    if args.hole_noise_mm is not None:
        env = dataclasses.replace(env, hole_obs_noise=args.hole_noise_mm / 1000.0)
    if args.break_force is not None:
        env = dataclasses.replace(env, break_force=args.break_force)
    overrides = {name: value for name, value in (
        ("break_sampling", args.break_sampling), ("force_sensor", args.force_sensor),
        ("force_frame", args.force_frame), ("spawn_noise_type", args.spawn_noise)) if value is not None}
    overrides["physics_backend"] = args.physics_backend
    if args.contact_timeconst is not None:
        overrides["contact_timeconst"] = args.contact_timeconst
    if args.peg_offset_mm is not None:
        overrides["randomization"] = ModelRandomization(peg_offset_range=tuple(v / 1000.0 for v in args.peg_offset_mm))
    for name in ("hole_obs_noise", "break_force"):
        overrides[name] = getattr(env, name)
    try:
        env = task_config(args.task, ppo.control, args.force_law, **overrides)
    except ValueError as err:
        raise SystemExit(f"train.py: error: {err}") from None
    if args.dynamics_randomization:
        env = dataclasses.replace(env, randomization=env.randomization.with_dynamics(
            **DYNAMICS_PRESETS[args.dynamics_randomization]))
    if args.arm_model_error:
        env = dataclasses.replace(env, randomization=env.randomization.with_arm_model_error())
    env = dataclasses.replace(env, controller=dataclasses.replace(env.controller,
                                                                  use_task_inertia=args.controller == "paper"))
    return RunSpec(ppo=ppo, env=env, num_seeds=args.seeds, seed=args.seed, preset=args.preset)


def main(argv=None) -> int:
    args = parse_args(argv)
    from match_jax import compile_cache

    compile_cache.enable()
    from match_jax.training.checkpoints import CheckpointError
    from match_jax.cli import unwritable
    from match_jax.training.runs import RunError, holds_run, train

    # the run directory, before anything is built or compiled
    if not args.resume and holds_run(args.out):
        print(f"error: --out {args.out} already holds a run: add --resume to continue it, or choose another --out",
              file=sys.stderr)
        return 2
    problem = unwritable(args.out, directory=True)
    if problem:
        print(f"error: --out {args.out} cannot be a run directory: {problem}", file=sys.stderr)
        return 2
    problem = unwritable(args.tensorboard, directory=True) if isinstance(args.tensorboard, pathlib.Path) else None
    if problem:
        print(f"error: --tensorboard {args.tensorboard}: {problem}", file=sys.stderr)
        return 2
    logger = None
    if args.tensorboard is not None:
        from match_jax.training.tb_logging import TensorBoardLogger, TensorBoardUnavailable
        try:
            logger = TensorBoardLogger(args.out / "tensorboard" if args.tensorboard is True else args.tensorboard)
        except TensorBoardUnavailable as err:
            print(f"error: --tensorboard: {err}", file=sys.stderr)
            return 2
    try:
        spec = None if args.resume else build_spec(args)
        summary = train(spec, args.out, resume=args.resume, progress=not args.no_progress, max_chunks=args.max_chunks,
                        time_budget_s=None if args.time_budget_min is None else 60.0 * args.time_budget_min,
                        total_steps=args.total_steps if args.resume else None, on_rows=logger)
    except (RunError, CheckpointError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM; train() said what was saved and how to resume
        return 130
    finally:
        if logger is not None:
            logger.close()
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
