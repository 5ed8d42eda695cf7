"""The real driver's speed with contacts detected and with contacts solved.

Configurations of `make(task, driver="real", real_contacts=..., kinematics=...)`:

    detect/lean    the default: contacts detected, not solved; the plain-jnp dynamics
                   (envs/dynamics.py) and pose-and-collision pass (envs/lean.py)
    detect/mjx     contacts detected, not solved; `mjx.step` of the contact-free model
                   and `mjx.collision` for the checks
    physical/mjx   MJX solves the contact forces at every substep (the behaviour before)

For each task and configuration, `BatchedEnv.step` runs inside a `lax.scan` with uniform
random joint targets (the env study's rollout and timing, `mara_mjx.bench.env.time_env`):
compile time (first call minus the median) apart from the steady state (median of
--repeats timed calls of --steps steps), env steps/s and physics steps/s (env steps/s x
substeps).

    python benchmarks/real_driver_speed.py                                  # on the GPU
    python benchmarks/real_driver_speed.py --envs 64 --steps 5 --out /tmp/speed.json  # CPU

XLA is configured as the benchmark studies do (`mara_mjx.bench.runner.configure`): full
float32 matmul precision, XLA's faster non-deterministic GPU ops unless --deterministic,
no persistent compilation cache (compile times are reported). Writes JSON to --out: the
command, device, versions (jax, mujoco, ...), the XLA settings, one record per (task,
configuration) and each detect configuration's speed-up over physical.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

DEFAULT_OUT = Path("benchmarks/results/real_driver_speed.json")


def main(argv: list[str] | None = None) -> None:
    from mara_mjx.envs.base import KINEMATICS, REAL_CONTACTS

    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--tasks", nargs="+", default=["MARACollisionOrient"])
    p.add_argument("--envs", type=int, default=16384, help="environments (default 16384)")
    p.add_argument("--steps", type=int, default=100, help="env steps per timed call")
    p.add_argument("--repeats", type=int, default=5, help="timed calls after the first")
    p.add_argument("--options", nargs="+", default=list(REAL_CONTACTS), choices=REAL_CONTACTS)
    p.add_argument(
        "--kinematics",
        nargs="+",
        default=["lean", "mjx"],
        choices=KINEMATICS,
        help="the detect configurations to time (physical is MJX's whatever this says)",
    )
    p.add_argument("--deterministic", action="store_true", help="deterministic GPU ops")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = p.parse_args(argv)
    for name in ("envs", "steps", "repeats"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be >= 1")

    from mara_mjx.bench.runner import configure, device_info, versions

    settings = configure(args.deterministic)  # before the backend starts

    from mara_mjx.bench.env import time_env

    configs = [
        (option, kinematics)
        for option in args.options
        for kinematics in (args.kinematics if option == "detect" else ["mjx"])
    ]
    records = []
    for task in args.tasks:
        for option, kinematics in configs:
            rec = time_env(
                task,
                "real",
                args.envs,
                args.steps,
                args.repeats,
                real_contacts=option,
                kinematics=kinematics,
            )
            rec.update(real_contacts=option, kinematics=kinematics)
            records.append(rec)
            print(
                f"{task:20s} {option + '/' + kinematics:13s} n={args.envs:>6d}"
                f"  {rec['env_steps_per_s'] / 1e6:8.4f} M env steps/s"
                f"  {rec['physics_steps_per_s'] / 1e6:8.3f} M physics steps/s"
                f"  compile {rec['compile_s']:5.1f} s",
                flush=True,
            )
    speedups = {}
    for task in args.tasks:
        sps = {
            f"{r['real_contacts']}/{r['kinematics']}": r["env_steps_per_s"]
            for r in records
            if r["task"] == task
        }
        if "physical/mjx" in sps:
            speedups[task] = {
                k: v / sps["physical/mjx"] for k, v in sps.items() if k.startswith("detect")
            }
            for k, v in speedups[task].items():
                print(f"{task}: {k} / physical = {v:.2f}x")
    out = {
        "command": shlex.join([Path(sys.executable).name, *sys.argv]),
        "device": device_info(),
        "versions": versions(),
        "settings": settings,
        "envs": args.envs,
        "steps_per_call": args.steps,
        "repeats": args.repeats,
        "records": records,
        "detect_over_physical": speedups,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
