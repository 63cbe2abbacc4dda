"""The paper's real-robot protocol on the MuJoCo C stand-in (`match_jax.transfer.standin`), for exported policies.

Per method: N noiseless trials of every seed's policy, then the seed with the most noiseless successes
(ties: fewer breaks) at each noise shell with M trials. Deployment as the paper's robot: Pose and
Hybrid-Basic sample their action with the std scaled to 5 % (exports made with `--stochastic`), VICES
and MATCH act deterministically; `--stochastic METHODS` names the sampled methods ('none': every method
deterministic). Writes OUT (JSON): per method its deployment, and per policy and level the stand-in's
summary (rates with 95 % Wilson intervals, mean / max force, energy) and its trials (`trial_rows`).
Resumable: levels already in OUT are kept (a method's deployment cannot change on resume).

    python benchmarks/standin_protocol.py --policies match=~/transfer/match --out results/transfer/standin.json
    python benchmarks/standin_protocol.py --policies pose=DIR,match=DIR --noiseless-trials 30 --shell-trials 50 \
        --out results/transfer/standin.json [--no-perturbation]

DIR holds policy_seed<i>.onnx + .json (`python -m match_jax.transfer.export RUN_DIR DIR --seed-index i`, with
`--stochastic` for a sampled method).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

from match_jax.transfer.standin import Perturbation, StandInConfig, run_trials

SHELLS_MM = (1.0, 2.5, 5.0, 7.5)
STOCHASTIC_METHODS = ("pose", "hybrid")  # the paper's robot ran these with the std scaled to 5 %


def _policies(text: str) -> dict[str, pathlib.Path]:
    out = {}
    for item in text.split(","):
        name, _, path = item.partition("=")
        if not name or not path:
            raise argparse.ArgumentTypeError(f"expected METHOD=DIR[,METHOD=DIR...], got {item!r}")
        out[name] = pathlib.Path(path).expanduser()
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policies", type=_policies, required=True, metavar="METHOD=DIR,...")
    parser.add_argument("--noiseless-trials", type=int, default=30)
    parser.add_argument("--shell-trials", type=int, default=50)
    parser.add_argument("--shells", default=",".join(f"{s:g}" for s in SHELLS_MM), help="shell levels, mm")
    parser.add_argument("--no-perturbation", action="store_true")
    parser.add_argument("--stochastic", default=",".join(STOCHASTIC_METHODS), metavar="METHODS",
                        help="methods that sample their exported stochastic action (default: %(default)s, the "
                             "paper's; 'none': all deterministic)")
    parser.add_argument("--out", type=pathlib.Path, required=True)
    args = parser.parse_args(argv)
    sampled = set() if args.stochastic == "none" else set(filter(None, args.stochastic.split(",")))
    unknown = sampled - set(STOCHASTIC_METHODS) - {"vices", "match"} - set(args.policies)
    if unknown:
        parser.error(f"--stochastic names no method: {','.join(sorted(unknown))!r}")
    config = StandInConfig(perturbation=Perturbation.none()) if args.no_perturbation else StandInConfig()
    results = json.loads(args.out.read_text()) if args.out.exists() else {}
    results.setdefault("config", {"no_perturbation": args.no_perturbation})

    def save():
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(results, indent=1, default=float) + "\n")
        tmp.replace(args.out)

    for method, folder in args.policies.items():
        seeds = sorted(folder.glob("policy_seed*.onnx"))
        if not seeds:
            parser.error(f"{folder} holds no policy_seed*.onnx")
        stochastic = method in sampled
        if stochastic and not all(json.loads(p.with_suffix(".json").read_text()).get("stochastic") for p in seeds):
            parser.error(f"{method} is sampled (--stochastic {args.stochastic!r}) but {folder} holds a policy "
                         "exported without --stochastic")
        deployment = "stochastic" if stochastic else "deterministic"
        entry = results.setdefault(method, {"deployment": deployment, "noiseless": {}, "shells": {}})
        if entry.get("deployment", "deterministic") != deployment:
            parser.error(f"{args.out} holds {method} run {entry.get('deployment', 'deterministic')}, "
                         f"not {deployment} (--stochastic {args.stochastic!r}); use another --out")
        for path in seeds:
            key = path.stem
            if key not in entry["noiseless"]:
                start = time.time()
                run = run_trials(path, args.noiseless_trials, 0.0, "shell", seed=0, config=config,
                                 stochastic=stochastic)
                entry["noiseless"][key] = {**run["summary"], "wall_clock_s": time.time() - start,
                                           "trial_rows": run["trials"]}
                save()
                print(f"[standin] {method} {key} noiseless: success {run['summary']['success_rate']:.2f}, "
                      f"breaks {run['summary']['broken_rate']:.2f} ({time.time() - start:.0f} s)", flush=True)
        best = max(entry["noiseless"], key=lambda k: (entry["noiseless"][k]["success_rate"],
                                                       -entry["noiseless"][k]["broken_rate"]))
        entry["best_seed"] = best
        for level in (float(x) for x in args.shells.split(",")):
            if f"{level:g}" in entry["shells"]:
                continue
            start = time.time()
            run = run_trials(folder / f"{best}.onnx", args.shell_trials, level, "shell", seed=1, config=config,
                             stochastic=stochastic)
            entry["shells"][f"{level:g}"] = {**run["summary"], "wall_clock_s": time.time() - start,
                                          "trial_rows": run["trials"]}
            save()
            print(f"[standin] {method} {best} shell {level:g} mm: success {run['summary']['success_rate']:.2f}, "
                  f"breaks {run['summary']['broken_rate']:.2f}", flush=True)
    save()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
