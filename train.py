"""Train a fragile peg-in-hole policy with PPO: Pose, VICES, Hybrid-Basic or MATCH.

    python train.py --method match --preset cpu --out runs/match_cpu
    python train.py --method pose --preset cpu --seeds 3 --total-steps 2000000 --out runs/pose_cpu
    python train.py --method match --no-ssl --preset paper --seeds 5 --out runs/match_nossl
    python train.py --method match --ppo.critic-steps 2 --env.contact-timeconst 0.05 --out runs/m  # any config field
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
from match_jax.cli import SHORT_NAMES, field_flag

METHODS = ("pose", "vices", "hybrid", "match")
TASKS = ("authors", "earlier", "authors_dr")  # match_jax.envs.tasks.TASKS
DYNAMICS = ("stable", "authors")  # match_jax.envs.randomization.DYNAMICS_PRESETS
RESUME_FLAGS = ("resume", "out", "total_steps", "max_chunks", "time_budget_min", "no_progress",
                "tensorboard")  # apply with --resume

EPILOG = """config fields:
  Every field of the learning config (PPOConfig, its network NetworkConfig) and of the task config
  (FPiHConfig, its controller, actions and randomization) is a flag: --ppo.FIELD, --ppo.network.FIELD,
  --env.FIELD, --env.controller.FIELD, ... (words joined by '-'; a tuple as its values one after another;
  True / False; None where a field may be None). They apply last, over the preset, the task and the
  flags above; the help below lists them with the defaults of the --preset, --method and --task given.
  Short names: """ + ", ".join(f"{short} = {field_flag(path)}" for short, path in SHORT_NAMES.items())


def _three_floats(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}") from None
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}")
    return values


def _parser():
    from match_jax.cli import Parser

    parser = Parser(prog="train.py", description=__doc__, epilog=EPILOG, add_help=False, allow_abbrev=False,
                    formatter_class=argparse.RawDescriptionHelpFormatter,
                    short_usage="--method {pose,vices,hybrid,match} --out DIR [options] | --resume --out DIR")
    parser.add_argument("-h", "--help", action="store_true",
                        help="this help, then every config field's flag with its default for the --preset, --method "
                             "and --task given")
    parser.add_argument("--method", choices=METHODS, help="pose | vices | hybrid (Hybrid-Basic) | match")
    parser.add_argument("--preset", choices=["cpu", "authors", "paper", "tiny"], default="cpu",
                        help="sizes and learning settings (default cpu; authors: the authors' code's recipe, for GPUs)")
    parser.add_argument("--task", choices=list(TASKS), default="authors",
                        help="task protocol: 'authors' (default: the authors' task, docs/protocol.md) or 'earlier' "
                             "(this project's earlier variant: rigid peg, peg contact force, peak break, damped "
                             "force law, gaussian spawn) or 'authors_dr' (the authors' task as their randomised runs "
                             "train it: their dynamics randomisation, end-effector noise 0.5 mm, no torque observed); "
                             "the flags below override single settings")
    parser.add_argument("--seeds", type=int, default=1, help="seeds trained together (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="base random seed")
    parser.add_argument("--total-steps", type=int, default=None, help="env steps per seed (preset default)")
    parser.add_argument("--out", type=pathlib.Path, help="run directory (required)")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its latest checkpoint")
    parser.add_argument("--max-chunks", type=int, default=None, help="stop after this many chunks (resumable)")
    parser.add_argument("--time-budget-min", type=float, default=None,
                        help="stop after the chunk that ends past this many minutes of wall clock (resumable)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--tensorboard", nargs="?", const=True, default=None, type=pathlib.Path, metavar="DIR",
                        help="also log the metrics as TensorBoard scalars to DIR (default: OUT/tensorboard); "
                             "needs tensorboardX (pip install 'match_jax[tensorboard]')")
    learning = parser.add_argument_group("learning (beside the --ppo.FIELD flags)")
    learning.add_argument("--no-ssl", action="store_true", help="no supervised selection loss (--ppo.ssl-coef 0)")
    learning.add_argument("--ssl-after-update", action="store_true",
                          help="experimental: SSL-only steps after the PPO epochs instead of inside every PPO loss "
                               "(--ppo.ssl-phase after)")
    learning.add_argument("--ssl-contact-only", action="store_true",
                          help="experimental: average the SSL over in-contact steps only (--ppo.ssl-samples contact)")
    learning.add_argument("--selection-not-in-ratio", action="store_true",
                          help="MATCH: leave the Bernoulli term out of the PPO ratio (authors' public code; "
                               "--ppo.selection-in-ratio False)")
    learning.add_argument("--set", nargs="+", action="extend", default=[], metavar="FIELD=VALUE",
                          help="learning settings by name, the same as --ppo.FIELD VALUE: critic_steps=2, "
                               "value_loss=huber, network.head_scale=0.14, ...")
    task = parser.add_argument_group("task settings (beside the --env.FIELD flags)")
    task.add_argument("--hole-noise-mm", type=float, default=None,
                      help="hole-position observation noise during training, mm (default 1, gaussian)")
    task.add_argument("--force-sensor", choices=["wrist", "peg_contact"], default=None,
                      help="force signal of the law, the 15 Hz break and the observation: the wrist F/T sensor "
                           "(default) or the sum of the peg's contact forces (no torque observed)")
    task.add_argument("--peg-offset-mm", type=_three_floats, default=None, metavar="X,Y,Z",
                      help="half-widths of the uniform peg offset in the hand, hand frame, mm (default 3,0,3; "
                           "0,0,0 = rigid)")
    task.add_argument("--controller", choices=["paper", "factory"], default="factory",
                      help="task-space law: IsaacLab Factory's u = J^T F as the authors' code runs it (default; "
                           "k_p = 100 N/m at the end effector) or the paper's equation u = J^T M_x F "
                           "(k_p x task inertia: 240-630 N/m at the spawn pose)")
    task.add_argument("--force-law", choices=["damped", "literal"], default=None,
                      help="force-controlled axes: the literal k_f (f_d - f), no feed-forward and no damping (the "
                           "authors', default) or k_f (f_d - f) + f_d - k_vf xdot")
    task.add_argument("--dynamics-randomization", nargs="?", const="stable", default=None, choices=DYNAMICS,
                      help="draw per episode peg mass x U[0.8, 1.2], peg friction U[0.5, 2.0], k_p U[60, 140] N/m, "
                           "rotational k_p U[20, 30] N m/rad and force gain U[0.05, 0.6] ('stable', the default); "
                           "'authors' draws the rotational k_p from the authors' U[20, 60], where the arm oscillates "
                           "above ~34 (docs/transfer.md)")
    task.add_argument("--arm-model-error", action="store_true",
                      help="draw per episode the robot's masses x U[0.99, 1.01] and rotor inertias x U[0.8, 1.25] "
                           "for the physics only; the control law keeps the nominal model (docs/transfer.md)")
    return parser


def parse_args(argv=None) -> argparse.Namespace:
    """The flags as a namespace; a fresh run's configs, every flag applied, in `ppo` and `env`."""
    from match_jax.cli import FieldError, fields_help, parse_fields, rewrite_short_names, set_assignments

    parser = _parser()
    args, rest = parser.parse_known_args(argv)
    for name in ("seeds", "total_steps", "max_chunks"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')} must be a positive integer, got {value}")
    if args.time_budget_min is not None and not (args.time_budget_min > 0 and math.isfinite(args.time_budget_min)):
        parser.error(f"--time-budget-min must be a positive number of minutes, got {args.time_budget_min}")
    if args.hole_noise_mm is not None and not (args.hole_noise_mm >= 0 and math.isfinite(args.hole_noise_mm)):
        parser.error(f"--hole-noise-mm must be a finite number >= 0, got {args.hole_noise_mm}")
    if args.help:
        print(parser.format_help())
        print(fields_help(_defaults(args, method=args.method or "match"), "train.py"))
        raise SystemExit(0)
    if args.out is None:
        parser.error("--out is required")
    if args.resume:  # the run's config.json defines it; only the budget and how this call runs may change
        ignored = [f"--{name.replace('_', '-')}" for name, value in vars(args).items()
                   if name not in RESUME_FLAGS and value != parser.get_default(name)] + rest[:1]
        if ignored:
            parser.error(f"--resume continues the run as its config.json defines it; {ignored[0].split('=')[0]} "
                         "cannot change it (only --total-steps, --max-chunks, --time-budget-min, --no-progress, "
                         "--tensorboard)")
    elif args.method is None:
        parser.error("--method is required (unless --resume)")
    if args.resume:
        return args
    try:
        tokens = rewrite_short_names(rest, SHORT_NAMES) + set_assignments(args.set, "ppo")
        configs = parse_fields(_defaults(args, method=args.method), tokens, "train.py")
    except (FieldError, ValueError) as err:
        parser.error(str(err))
    args.ppo, args.env = configs["ppo"], configs["env"]
    if args.no_ssl and args.ppo.ssl_coef != 0:
        parser.error(f"--no-ssl sets the selection loss's weight to 0; --ssl-coef {args.ppo.ssl_coef} contradicts it")
    if args.ppo.method != args.method or args.env.control != args.ppo.control:
        parser.error(f"--method {args.method} sets the method and its controller; --ppo.method and --env.control "
                     "cannot change them")
    force_z, (low, high) = args.ppo.network.initial_force_z, args.env.actions.force_z_range
    if force_z is not None and not low <= force_z <= high:
        parser.error(f"--initial-force-z must be in [{low:g}, {high:g}] N (the force-z action range), got {force_z}")
    if args.env.physics_backend == "warp":
        from match_jax.envs import sim

        if not sim.warp_installed():
            parser.error(f"--physics-backend warp {sim.WARP_MISSING}")
    return args


def _defaults(args: argparse.Namespace, method: str) -> dict:
    """The learning and task configs of the preset, method and task flags, before the config-field flags."""
    from match_jax.envs.randomization import DYNAMICS_PRESETS
    from match_jax.envs.tasks import task_config
    from match_jax.training.presets import get_preset

    overrides = {"method": method}
    if args.total_steps is not None:
        overrides["total_steps"] = args.total_steps
    if args.no_ssl:
        overrides["ssl_coef"] = 0.0
    if args.selection_not_in_ratio:
        overrides["selection_in_ratio"] = False
    if args.ssl_after_update:
        overrides["ssl_phase"] = "after"
    if args.ssl_contact_only:
        overrides["ssl_samples"] = "contact"
    ppo = get_preset(args.preset, **overrides)
    settings = {}
    if args.hole_noise_mm is not None:
        settings["hole_obs_noise"] = args.hole_noise_mm / 1000.0
    if args.force_sensor is not None:
        settings["force_sensor"] = args.force_sensor
    env = task_config(args.task, ppo.control, args.force_law, **settings)
    if args.peg_offset_mm is not None:  # the task's other draws (authors_dr: its dynamics) stay
        env = dataclasses.replace(env, randomization=dataclasses.replace(
            env.randomization, peg_offset_range=tuple(v / 1000.0 for v in args.peg_offset_mm)))
    if args.dynamics_randomization:
        env = dataclasses.replace(env, randomization=env.randomization.with_dynamics(
            **DYNAMICS_PRESETS[args.dynamics_randomization]))
    if args.arm_model_error:
        env = dataclasses.replace(env, randomization=env.randomization.with_arm_model_error())
    env = dataclasses.replace(env, controller=dataclasses.replace(env.controller,
                                                                  use_task_inertia=args.controller == "paper"))
    return {"ppo": ppo, "env": env}


def build_spec(args: argparse.Namespace):
    """The RunSpec of a fresh run's parsed flags."""
    from match_jax.training.runs import RunSpec

    return RunSpec(ppo=args.ppo, env=args.env, num_seeds=args.seeds, seed=args.seed, preset=args.preset)


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
