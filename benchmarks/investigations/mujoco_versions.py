"""Does the MuJoCo version change the physics? Dumps the compiled scene's model arrays and 400 steps of
MuJoCo C and MJX (zero control, from the reset state) under the installed mujoco; `--compare` diffs two dumps.

    python benchmarks/investigations/mujoco_versions.py dump /tmp/mj_a.npz      # in one environment
    python benchmarks/investigations/mujoco_versions.py dump /tmp/mj_b.npz      # in another
    python benchmarks/investigations/mujoco_versions.py compare /tmp/mj_a.npz /tmp/mj_b.npz

Needs only mujoco, mujoco-mjx and jax (not match_jax's other dependencies).
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np

SCENE = pathlib.Path(__file__).resolve().parents[2] / "match_jax" / "envs" / "assets" / "fpih_scene.xml"
MODEL_FIELDS = ("body_mass", "body_inertia", "body_pos", "geom_size", "geom_pos", "geom_friction", "geom_solref",
                "geom_solimp", "dof_damping", "dof_armature", "jnt_range", "actuator_gainprm")
OPTION_FIELDS = ("timestep", "impratio", "iterations", "ls_iterations")
STEPS = 400


def dump(path: str) -> None:
    import jax
    import mujoco
    from mujoco import mjx

    model = mujoco.MjModel.from_xml_path(str(SCENE))
    out = {name: np.asarray(getattr(model, name), float) for name in MODEL_FIELDS}
    out.update({f"opt.{name}": np.atleast_1d(float(getattr(model.opt, name))) for name in OPTION_FIELDS})
    data = mujoco.MjData(model)
    c_qpos = []
    for _ in range(STEPS):
        mujoco.mj_step(model, data)
        c_qpos.append(data.qpos.copy())
    mx = mjx.put_model(model)
    step = jax.jit(lambda d: mjx.step(mx, d))
    d, mjx_qpos = mjx.make_data(mx), []
    for _ in range(STEPS):
        d = step(d)
        mjx_qpos.append(np.asarray(d.qpos))
    np.savez(path, c_qpos=np.array(c_qpos), mjx_qpos=np.array(mjx_qpos), version=np.array(mujoco.__version__), **out)
    print(f"mujoco {mujoco.__version__}: {path}")


def compare(a_path: str, b_path: str) -> None:
    a, b = np.load(a_path), np.load(b_path)
    print(f"{a['version']} vs {b['version']}")
    for key in a.files:
        if key != "version":
            print(f"{key:20s} max |difference| {np.max(np.abs(a[key] - b[key])):.3g}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("dump").add_argument("out")
    cmp = sub.add_parser("compare")
    cmp.add_argument("a")
    cmp.add_argument("b")
    args = parser.parse_args()
    dump(args.out) if args.command == "dump" else compare(args.a, args.b)
