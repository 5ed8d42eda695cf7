"""Sim-to-real robustness table: three training recipes on randomised real-driver physics.

Three training recipes (issue 13), each evaluated with the real driver on randomised
physics drawn from a held-out seed.

    python benchmarks/sim2real.py --out $OUT                 # one GPU, < 9 minutes
    python benchmarks/sim2real.py --out /tmp/s2r --tiny      # CPU smoke test (minutes)

Recipes (the default PPO preset, seed --seed, on --env, MARACollision by default: it
penalises collisions, which act physically under the real driver):

    a  train driver                        --steps_train env steps (default 2.5e7)
    b  train driver + randomisation        --steps_train env steps
    c  real driver  + randomisation        --steps_real env steps (default 2e7; the real
                                           driver's step costs ~30x the train driver's)

Randomisation: `RandomizeConfig()`'s defaults (mara_mjx/envs/randomize.py). Evaluation:
--draws (1,000) environments with the real driver, each its own physics draw (masses,
inertias, damping, friction, armature, servo gains, zero offsets, q noise, latency of
0-1 steps) from the held-out seed --eval_seed, reset noise 0.02 rad, run for
--eval_steps control steps (300 = 15 s); the error is the true TCP error at the last
step, per axis (mm). At 0.3 and 0.5 rad/s: mean, median, p95 and worst per axis,
fractions within 5 mm and 1 mm on every axis, the fractions of episodes with a
collision and with a physics blow-up, and the five worst draws with their parameters.
Sweeps at --sweep_velocity: the default draws with the latency fixed at 0, 1, 2, 3
steps, and with the zero offsets' half-width at 0, 0.5, 1, 2, 4 mrad.

Writes OUT/sim2real.json (everything, with timings and versions) and OUT/sim2real.md
(the tables), after every phase, so a run cut short keeps what it measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import mara_mjx
from mara_mjx.cli.common import configure_jax
from mara_mjx.envs.randomize import RandomizeConfig
from mara_mjx.ppo.policy import Policy, make_policy
from mara_mjx.ppo.presets import PRESETS
from mara_mjx.ppo.train import make_train

RECIPES = {
    "a": ("train driver", "train", False),
    "b": ("train driver + randomisation", "train", True),
    "c": ("real driver + randomisation", "real", True),
}
LATENCIES = (0, 1, 2, 3)
OFFSETS_MRAD = (0.0, 0.5, 1.0, 2.0, 4.0)
VELOCITIES = (0.3, 0.5)
NOMINAL = RandomizeConfig.off()  # every range at the nominal model


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder for sim2real.json and sim2real.md")
    p.add_argument("--env", default="MARACollision", help="registered task (fixed target)")
    p.add_argument("--steps_train", type=float, default=2.5e7, help="env steps, recipes a, b")
    p.add_argument("--steps_real", type=float, default=2e7, help="env steps, recipe c")
    p.add_argument("--draws", type=int, default=1000, help="evaluation physics draws")
    p.add_argument("--eval_steps", type=int, default=300, help="evaluation episode length")
    p.add_argument("--seed", type=int, default=0, help="training seed")
    p.add_argument("--eval_seed", type=int, default=12345, help="held-out evaluation seed")
    p.add_argument("--sweep_velocity", type=float, default=0.5, help="rad/s of the sweeps")
    p.add_argument("--recipes", default="abc", help="which recipes to run (subset of abc)")
    p.add_argument("--tiny", action="store_true", help="CPU smoke test: tiny everything")
    p.add_argument(
        "--keep",
        default=None,
        help="an earlier run's sim2real.json: its recipes not in --recipes are kept in the "
        "report (with that run's command) until this run replaces them",
    )
    return p.parse_args(argv)


def train(env_name: str, driver: str, randomize: bool, steps: float, args) -> tuple:
    """(policy, seconds, env steps) of one recipe."""
    env = mara_mjx.make(env_name, driver=driver, randomize=randomize)
    config = PRESETS["default"].replace(total_timesteps=int(steps), seed=args.seed)
    if args.tiny:
        config = config.replace(num_envs=8, num_steps=4, num_minibatches=2, total_timesteps=64)
    start = time.monotonic()
    trainer = make_train(env, config, updates_per_call=min(10, config.ppo.num_updates))
    state = trainer.init(jax.random.key(config.ppo.seed))
    done = 0
    while done < trainer.num_updates:
        n = min(trainer.updates_per_call, trainer.num_updates - done)
        state, _ = trainer.run(state, n)
        done += n
        if done % (10 * trainer.updates_per_call) == 0 or done == trainer.num_updates:
            jax.block_until_ready(state.params)
            print(f"  {done}/{trainer.num_updates} updates, {time.monotonic() - start:.0f} s")
    jax.block_until_ready(state.params)
    seconds = time.monotonic() - start
    policy = make_policy(state, trainer.config)
    return policy, seconds, done * trainer.steps_per_update


def make_evaluator(env_name: str, draws: int, steps: int, config, tiny: bool):
    """(env, jitted fn(policy params, obs stats, env params, key) -> per-draw results);
    one compile serves every policy, velocity and sweep (all traced)."""
    env = mara_mjx.make(
        env_name,
        driver="real",
        randomize=True,
        randomization=RandomizeConfig(latency_steps=(0, max(LATENCIES))),
        reset_noise=0.02,
        max_episode_steps=steps,
    )
    del tiny

    @jax.jit
    def evaluate(params, stats, env_params, key):
        policy = Policy(params=params, obs_stats=stats, config=config, action_size=6)
        keys = jax.random.split(key, draws)
        s = jax.vmap(env.reset, in_axes=(0, None))(keys, env_params)

        def body(s, _):
            action = policy(s.obs)
            s = jax.vmap(env.step)(s, action)
            # the policy's raw (unclipped) action: large values mean it pushes into a limit
            step_rad = jnp.max(jnp.abs(action), axis=-1)
            return s, (s.metrics["collided"], s.metrics["physics_blowup"], step_rad)

        s, (collided, blowup, step_rad) = jax.lax.scan(body, s, None, length=steps)
        r = s.params.randomization
        hit = collided > 0
        return {
            "error_mm": 1000.0 * s.metrics["position_error"],
            "collided": jnp.any(hit, axis=0),
            "blowup": jnp.any(blowup > 0, axis=0),
            # diagnostics: when the first collision happens, the largest raw action
            # entry (rad), the final measured q
            "first_collision": jnp.where(jnp.any(hit, axis=0), jnp.argmax(hit, axis=0), steps),
            "max_step_rad": jnp.max(step_rad, axis=0),
            "final_q": s.obs[:, :6],
            "draw": r.draw,
        }

    return env, evaluate


def summarise(out: dict, worst: int = 5) -> dict:
    err = np.asarray(out["error_mm"], np.float64)  # (draws, 3)
    worst_axis = err.max(axis=1)
    order = np.argsort(-worst_axis)[:worst]
    draw = {k: np.asarray(v) for k, v in out["draw"].items()}
    return {
        "mean_mm": err.mean(axis=0).round(3).tolist(),
        "median_mm": np.median(err, axis=0).round(3).tolist(),
        "p95_mm": np.percentile(err, 95, axis=0).round(3).tolist(),
        "worst_mm": err.max(axis=0).round(3).tolist(),
        "within_5mm": float(np.mean(worst_axis <= 5.0)),
        "within_1mm": float(np.mean(worst_axis <= 1.0)),
        "collision_rate": float(np.mean(np.asarray(out["collided"]))),
        "physics_blowup_rate": float(np.mean(np.asarray(out["blowup"]))),
        "first_collision_step_median": float(np.median(np.asarray(out["first_collision"]))),
        "max_step_rad_median": float(np.median(np.asarray(out["max_step_rad"]))),
        "final_q_median": np.median(np.asarray(out["final_q"]), axis=0).round(3).tolist(),
        "worst_cases": [
            {
                "error_mm": err[i].round(3).tolist(),
                "collided": bool(np.asarray(out["collided"])[i]),
                **{k: np.round(v[i], 5).tolist() for k, v in draw.items()},
            }
            for i in order
        ],
    }


def write(out_dir: Path, report: dict) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "sim2real.json").write_text(json.dumps(report, indent=1))
    (out_dir / "sim2real.md").write_text(markdown(report))


def _axes(values) -> str:
    return ", ".join(f"{v:.2f}" for v in values)


def markdown(report: dict) -> str:
    lines = [
        f"# Sim-to-real robustness: {report['env']} ({report['device']})",
        "",
        f"Command: `{report['command']}`",
        "",
        f"{report['draws']} randomised physics draws (held-out seed {report['eval_seed']}), "
        f"real driver, {report['eval_steps']} control steps; error = true TCP error at the "
        "last step (mm).",
        "",
        "| recipe | trained (env steps, s) | velocity | mean x, y, z | p95 x, y, z | worst "
        "x, y, z | within 5 / 1 mm | collisions | blow-ups |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for key, rec in report["recipes"].items():
        for v, s in rec.get("eval", {}).items():
            lines.append(
                f"| {key}: {rec['name']} | {rec['env_steps']:.3g}, {rec['train_s']:.0f} s | {v} "
                f"| {_axes(s['mean_mm'])} | {_axes(s['p95_mm'])} | {_axes(s['worst_mm'])} | "
                f"{100 * s['within_5mm']:.1f}% / {100 * s['within_1mm']:.1f}% | "
                f"{100 * s['collision_rate']:.1f}% | {100 * s['physics_blowup_rate']:.1f}% |"
            )
    diag = [k for k, r in report["recipes"].items() if "nominal" in r]
    if diag:
        lines += [
            "",
            f"Diagnostics at {report['sweep_velocity']} rad/s: the real driver on the nominal "
            "model (no randomisation); on the randomised draws, the median step of the first "
            "collision (the episode's length if none) and the median final measured q:",
            "",
            "| recipe | nominal: mean x, y, z | nominal: collisions | first collision (step) "
            "| final q (median) |",
            "|---|---|---|---|---|",
        ]
        for k in diag:
            r = report["recipes"][k]
            n = r["nominal"]
            e = r["eval"][f"{report['sweep_velocity']} rad/s"]
            lines.append(
                f"| {k}: {r['name']} | {_axes(n['mean_mm'])} | {100 * n['collision_rate']:.1f}% "
                f"| {e['first_collision_step_median']:.0f} | {_axes(e['final_q_median'])} |"
            )
    commands = {r["command"] for r in report["recipes"].values() if "command" in r}
    if commands:
        lines += ["", "Recipes kept from an earlier run: " + "; ".join(f"`{c}`" for c in commands)]
    for sweep, label, unit in (("latency", "latency", "steps"), ("offset", "offset", "mrad")):
        keys = [k for k, r in report["recipes"].items() if sweep in r]
        if not keys:
            continue
        points = list(report["recipes"][keys[0]][sweep])
        lines += [
            "",
            f"Mean per-axis error (mm) and within 5 mm against the {label} ({unit}), at "
            f"{report['sweep_velocity']} rad/s, other parameters as drawn:",
            "",
            f"| recipe | {' | '.join(f'{label} {p}' for p in points)} |",
            "|---|" + "---|" * len(points),
        ]
        for k in keys:
            cells = [
                f"{np.mean(s['mean_mm']):.2f} ({100 * s['within_5mm']:.0f}%)"
                for s in report["recipes"][k][sweep].values()
            ]
            lines.append(f"| {k}: {report['recipes'][k]['name']} | {' | '.join(cells)} |")
    lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = parse_args(argv)
    configure_jax()
    if args.tiny:
        args.draws, args.eval_steps = 4, 4
    out_dir = Path(args.out)
    start = time.monotonic()
    report = {
        "env": args.env,
        "command": " ".join(["python", *sys.argv]),
        "device": str(jax.devices()[0].device_kind),
        "draws": args.draws,
        "eval_steps": args.eval_steps,
        "eval_seed": args.eval_seed,
        "sweep_velocity": args.sweep_velocity,
        "randomization": dataclasses.asdict(RandomizeConfig()),
        "versions": {"jax": jax.__version__, "python": platform.python_version()},
        "recipes": {},
        "timings_s": {},
    }
    if args.keep:
        kept = json.loads(Path(args.keep).read_text())
        for key, rec in kept["recipes"].items():
            # replaced when this run's recipe of the same key has trained
            report["recipes"][key] = {**rec, "command": kept["command"]}
        report["recipes"] = dict(sorted(report["recipes"].items()))
    evaluator = None
    eval_key = jax.random.key(args.eval_seed)
    for key in args.recipes:
        name, driver, randomize = RECIPES[key]
        steps = args.steps_real if driver == "real" else args.steps_train
        policy, seconds, env_steps = train(args.env, driver, randomize, steps, args)
        rec = {"name": name, "driver": driver, "randomize": randomize, "train_s": seconds,
               "env_steps": env_steps}  # fmt: skip
        report["recipes"][key] = rec
        report["recipes"] = dict(sorted(report["recipes"].items()))
        print(f"{key} ({name}): {env_steps:.3g} env steps in {seconds:.0f} s", flush=True)
        write(out_dir, report)
        if evaluator is None:
            # the network settings of the first recipe; every recipe shares them
            env, evaluator = make_evaluator(
                args.env, args.draws, args.eval_steps, policy.config, args.tiny
            )
        t = time.monotonic()

        def run(**overrides):
            params = env.make_params(**overrides)
            out = evaluator(policy.params, policy.obs_stats, params, eval_key)
            return summarise(jax.device_get(out))

        rec["eval"] = {
            f"{v} rad/s": run(velocity=v, randomization=RandomizeConfig()) for v in VELOCITIES
        }
        # the real driver on the nominal model (every range collapsed): separates the
        # driver's effect from the randomisation's
        rec["nominal"] = run(velocity=args.sweep_velocity, randomization=NOMINAL)
        v = args.sweep_velocity
        rec["latency"] = {
            str(k): run(velocity=v, randomization=RandomizeConfig(latency_steps=(k, k)))
            for k in LATENCIES
        }
        rec["offset"] = {
            str(w): run(velocity=v, randomization=RandomizeConfig(calibration_offset=w / 1000))
            for w in OFFSETS_MRAD
        }
        rec["eval_s"] = time.monotonic() - t
        for label, s in rec["eval"].items():
            print(
                f"  {label}: mean {_axes(s['mean_mm'])} mm, within 5 mm "
                f"{100 * s['within_5mm']:.1f}%, 1 mm {100 * s['within_1mm']:.1f}%",
                flush=True,
            )
        report["timings_s"]["total"] = time.monotonic() - start
        write(out_dir, report)
    print(markdown(report))
    print(f"wrote {out_dir / 'sim2real.json'} and sim2real.md in {time.monotonic() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
