"""Evaluate trained policies (a run directory) or a scripted baseline on fragile peg-in-hole.

    python eval.py runs/match_cpu --episodes 100 --json results/match_eval.json
    python eval.py runs/match_cpu --noise-sweep 1,2.5,5,7.5 --episodes 500     # the authors' shells
    python eval.py runs/match_cpu --unbreakable --checkpoint latest
    python eval.py --baseline spiral --episodes 100 --noise-mm 1 --json results/spiral.json
    python eval.py runs/match_cpu --episodes 100 --render results/match_episode.png  # + image strip and GIF
    python eval.py runs/match_cpu --env.contact-timeconst 0.05     # any field of the run's task config
    python eval.py runs/match_cpu --mean-action pre_tanh           # the authors' deterministic action

A run is evaluated for every seed with the deterministic policy (tanh of the mean, force control
where p_force > 0.5; --mean-action pre_tanh: the pre-tanh mean, unclipped) with one compiled rollout,
run once per seed and noise level, at the training noise unless --noise-mm / --noise-sweep say otherwise.
Printed: per seed and mean +- standard error over seeds of success %, break %, time to success (s) and
mean contact force (N), time and force by the authors' definitions, with a legend line (--all-columns adds
ours, both break checks and, for hybrid policies, the force-selection rates). The JSON (--json) holds every column. Every field of the run's task config
(FPiHConfig and its nested configs) is a flag, --env.FIELD or --env.controller.FIELD, ..., as train.py's
--help lists them; they replace the run's values for this evaluation.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import sys
import time

import match_jax  # noqa: F401  (sets the fast XLA CPU flag before JAX starts)


def parse_args(argv=None) -> argparse.Namespace:
    from match_jax.cli import Parser, parse_fields, split_field_flags

    parser = Parser(prog="eval.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                    short_usage="RUN_DIR [options] | --baseline {spiral,pose} [options]")
    parser.add_argument("run_dir", nargs="?", type=pathlib.Path, help="training run directory to evaluate")
    parser.add_argument("--baseline", choices=["spiral", "pose"], help="evaluate a scripted policy instead")
    parser.add_argument("--episodes", type=int, default=100, help="episodes (per seed for a run; default 100)")
    parser.add_argument("--noise-mm", type=float, default=None,
                        help="hole-position observation noise in mm (sd for gaussian, half-width for uniform); "
                             "default: a run's training noise, 1 mm for baselines")
    parser.add_argument("--noise-type", choices=["gaussian", "uniform", "shell"], default=None,
                        help="gaussian (default), uniform per axis, or shell: a random 3-D direction times a "
                             "radius U[previous edge of 0,1,2.5,5,7.5 mm, level] (the authors' sweep, the default "
                             "with --noise-sweep)")
    parser.add_argument("--noise-sweep", type=str, default=None, help="comma-separated noise levels in mm")
    parser.add_argument("--checkpoint", choices=["best", "latest"], default="best", help="which policy of a run")
    parser.add_argument("--break-force", type=float, default=None,
                        help="break threshold in N (default: a run's training value; 10 for baselines)")
    parser.add_argument("--unbreakable", action="store_true", help="no break threshold")
    parser.add_argument("--batch", type=int, default=0,
                        help="scripted baselines: episodes per jitted batch (default: all)")
    parser.add_argument("--physics-backend", choices=["jax", "warp"], default=None,
                        help="evaluate a run's policies on this physics backend (default: the run's own)")
    parser.add_argument("--mean-action", choices=["tanh", "pre_tanh"], default="tanh",
                        help="a run's deterministic action: tanh of the policy's mean (default) or the pre-tanh "
                             "mean, unclipped, as the authors' simulated evaluation sends it")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=pathlib.Path, default=None, help="write the results here (every column)")
    parser.add_argument("--all-columns", action="store_true",
                        help="a run's table with every column: our time and force beside the authors', both break "
                             "checks, the force-selection rates (default: success, break, time, force)")
    parser.add_argument("--render", type=pathlib.Path, default=None,
                        help="also save a PNG image strip of one episode (seed 0 of a run) here, and a video of "
                             "it beside the strip (same name, the video format's suffix)")
    parser.add_argument("--video-format", choices=["gif", "mp4"], default=None,
                        help="video beside the --render strip: gif (default, Pillow) or mp4 (needs imageio and "
                             "imageio-ffmpeg: pip install 'match_jax[video]')")
    argv, env_flags = list(sys.argv[1:] if argv is None else argv), []
    if any(token.startswith("--env.") for token in argv):
        from match_jax.envs import FPiHConfig

        argv, env_flags = split_field_flags(argv, {"env": FPiHConfig()})
    args = parser.parse_args(argv)
    args.env_config = None
    if (args.run_dir is None) == (args.baseline is None):
        parser.error("give either a RUN_DIR or --baseline spiral|pose")
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.noise_mm is not None and not (args.noise_mm >= 0 and math.isfinite(args.noise_mm)):
        parser.error(f"--noise-mm must be a finite number >= 0, got {args.noise_mm}")
    if args.noise_sweep is not None:
        if args.noise_mm is not None:
            parser.error("--noise-mm and --noise-sweep exclude each other")
        try:
            args.noise_levels = [float(x) for x in args.noise_sweep.split(",") if x.strip()]
        except ValueError:
            parser.error(f"--noise-sweep must be comma-separated numbers in mm, got {args.noise_sweep!r}")
        bad = [x for x in args.noise_levels if not (x >= 0 and math.isfinite(x))]
        if bad or not args.noise_levels:
            parser.error(f"--noise-sweep levels must be finite numbers >= 0, got {args.noise_sweep!r}")
    if args.break_force is not None and not args.break_force > 0:
        parser.error(f"--break-force must be > 0 N, got {args.break_force}")
    if args.run_dir is None and args.break_force is None:
        args.break_force = 10.0
    if args.batch < 0:
        parser.error(f"--batch must be >= 0, got {args.batch}")
    if args.baseline is not None and args.mean_action != "tanh":
        parser.error(f"--mean-action {args.mean_action} applies to a run's policies, not to --baseline")
    if args.video_format is not None and args.render is None:
        parser.error("--video-format needs --render PATH (the video is written beside the strip)")
    args.video_format = args.video_format or "gif"
    if env_flags:  # the run's task config with those fields replaced, checked before any work
        if args.run_dir is None:
            parser.error(f"{env_flags[0]}: --env.FIELD flags replace fields of a run's task config; not with "
                         "--baseline")
        from match_jax.training.runs import RunError, load_spec

        try:
            env = load_spec(args.run_dir).env
            args.env_config = parse_fields({"env": env}, env_flags, "eval.py")["env"]
        except (RunError, ValueError) as err:
            parser.error(str(err))
        if (args.env_config.control, args.env_config.observe_torque) != (env.control, env.observe_torque):
            parser.error("--env.control and --env.observe-torque must stay the run's: its policies act and observe "
                         "through them")
    return args


def format_table(summary: dict) -> str:
    rows = [
        ("episodes", f"{summary['episodes']}"),
        ("success %", f"{100 * summary['success_rate']:.1f}"),
        ("break %", f"{100 * summary['break_rate']:.1f}"),
        ("time to success (s)", f"{summary['mean_time_to_success_s']:.2f}"),
        ("mean contact force (N)", f"{summary['mean_force_n']:.2f}"),
    ]
    title = (f"{summary['baseline']} baseline, hole noise {summary['noise_mm']:g} mm ({summary['noise_type']}), "
             f"break force {summary['break_force_n'] or 'none'}")
    width = max(len(k) for k, _ in rows)
    return "\n".join([title] + [f"  {k:<{width}}  {v:>8}" for k, v in rows])


def evaluate_run_dir(args) -> dict:
    """Evaluate a run at one noise level or over a sweep; returns the JSON document."""
    from match_jax.training.evaluation import evaluate_run_grid, format_result
    from match_jax.training.runs import load_spec

    load_spec(args.run_dir)  # a one-line RunError unless it is a run directory
    break_force = math.inf if args.unbreakable else args.break_force
    levels = args.noise_levels if args.noise_sweep is not None else (
        None if args.noise_mm is None else [args.noise_mm])
    noise_type = args.noise_type or ("shell" if args.noise_sweep is not None else None)
    results = evaluate_run_grid(args.run_dir, args.episodes, levels, noise_type,
                                None if break_force is None else [break_force], args.checkpoint, 1000 + args.seed,
                                physics_backend=args.physics_backend, env_config=args.env_config,
                                mean_action=args.mean_action)
    for result in results:
        print(format_result(result, all_columns=args.all_columns))
    return results[0] if args.noise_sweep is None else {"noise_sweep": results}


def choose_gl_backend() -> None:
    """Headless Linux: use EGL for offscreen rendering when libEGL is installed (MuJoCo reads MUJOCO_GL
    when `mujoco` is first imported, so this runs before that). Otherwise MuJoCo's default stays and
    rendering reports itself unavailable."""
    import ctypes.util

    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") and "MUJOCO_GL" not in os.environ:
        if ctypes.util.find_library("EGL"):
            os.environ["MUJOCO_GL"] = "egl"


def video_path(strip: pathlib.Path, video_format: str) -> pathlib.Path:
    """Where the video of a --render strip goes: beside it, same name, the format's suffix."""
    path = strip.with_suffix(f".{video_format}")
    return path if path != strip else strip.with_name(f"{strip.stem}_video.{video_format}")


def render_episode(args) -> None:
    """Save an image strip and a video of one episode (the run's first seed, or the baseline): the strip to
    args.render, the video beside it (`video_path`)."""
    import jax

    from match_jax.envs import baselines
    from match_jax.training import render

    if args.run_dir is not None:
        from match_jax.rl.ppo import deterministic_policy
        from match_jax.training.runs import load_policy

        run, policy_params = load_policy(args.run_dir, 0, args.checkpoint, args.physics_backend)
        env = run.env
        squash = args.mean_action == "tanh"
        if args.env_config is not None or not squash:
            import dataclasses

            from match_jax.envs import FPiHEnv

            config = dataclasses.replace(args.env_config or env.config, physics_backend=env.config.physics_backend)
            if not squash:  # the authors' env takes the pre-tanh mean unclipped
                config = dataclasses.replace(config, actions=dataclasses.replace(config.actions, clip=False))
            env = FPiHEnv(config)
        policy = deterministic_policy(run.trainer, squash)
        policy_state = (policy_params["params"], policy_params["policy_stats"])
        title = render.run_title(run.spec, args.run_dir, 0, args.checkpoint) + (
            "" if squash else ", pre-tanh mean actions")
    else:
        from match_jax.training.evaluation import baseline_env

        noise_mm = 1.0 if args.noise_mm is None else args.noise_mm
        env = baseline_env(args.baseline, noise_mm / 1000.0, args.noise_type or "gaussian",
                           math.inf if args.unbreakable else args.break_force)
        policy, policy_state = baselines.make_baseline(args.baseline, env)
        title = f"{args.baseline} baseline, hole noise {noise_mm:g} mm"
    states = render.record_episode(env, policy, policy_state, jax.random.PRNGKey(args.seed))
    try:
        path = render.render_strip(env, states, args.render, title=title)
    except render.RenderUnavailable as err:
        print(f"no image strip or video: {err}", file=sys.stderr)
        return
    print(f"wrote {path}")
    print(f"wrote {render.render_video(env, states, video_path(args.render, args.video_format))}")


def output_problems(args) -> list[str]:
    """One line per output path (--json, --render and its video) that cannot be written."""
    from match_jax.cli import unwritable

    paths = [("--json", args.json)]
    if args.render:
        paths += [("--render", args.render), ("--render (video)", video_path(args.render, args.video_format))]
    problems = []
    for flag, path in paths:
        problem = None if path is None else unwritable(path)
        if problem:
            problems.append(f"{flag} {path}: {problem}")
    return problems


def write_json(summary: dict, path: pathlib.Path) -> bool:
    """Write the results to `path`; if that fails, print them to stdout, save them to a file in the temp
    directory and say both in one line on stderr. Whether `path` was written."""
    text = json.dumps(summary, indent=2, allow_nan=True)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    except OSError as err:
        import tempfile

        print(text)
        fd, fallback = tempfile.mkstemp(prefix="eval_", suffix=".json")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        print(f"error: cannot write --json {path} ({err.strerror or err}); the results are printed above and "
              f"saved to {fallback}", file=sys.stderr)
        return False
    print(f"wrote {path}")
    return True


def main(argv=None) -> int:
    args = parse_args(argv)
    problems = output_problems(args)
    if problems:  # before any work
        print(f"error: {problems[0]}", file=sys.stderr)
        return 2
    from match_jax import compile_cache

    compile_cache.enable()
    if args.render:
        choose_gl_backend()
        from match_jax.training.render import VIDEO_INSTALL, missing_video_packages

        missing = missing_video_packages(args.video_format)
        if missing:
            print(f"error: --video-format {args.video_format} needs {', '.join(missing)}: "
                  f"{VIDEO_INSTALL[args.video_format]}", file=sys.stderr)
            return 2
    start = time.time()
    if args.run_dir is not None:
        from match_jax.training.checkpoints import CheckpointError
        from match_jax.training.runs import RunError
        try:
            summary = evaluate_run_dir(args)
        except (RunError, CheckpointError) as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
    else:
        noise_mm = 1.0 if args.noise_mm is None else args.noise_mm
        from match_jax.training.evaluation import evaluate_baseline

        summary = evaluate_baseline(args.baseline, args.episodes, noise_mm / 1000.0, args.noise_type or "gaussian",
                                    math.inf if args.unbreakable else args.break_force, args.seed, args.batch)
        print(format_table(summary))
    summary["wall_clock_s"] = round(time.time() - start, 1)
    if args.json and not write_json(summary, args.json):
        return 1
    if args.render:
        try:
            render_episode(args)
        except OSError as err:
            print(f"error: cannot write --render {args.render} or its video ({err.strerror or err})", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
