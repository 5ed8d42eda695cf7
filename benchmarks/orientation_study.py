"""Fixed-target study: several seeds per (task, variant) in one program (the paper table's runs).

Orientation study (issue 11): why the Orient policies settle off the target pose, and
which trainer-side changes fix it. Several seeds of each (task, variant) train in one
vmapped program (ppo.members.make_seed_trainer); every `--chunk` updates a deterministic
probe records, per seed, where the policy takes the arm:

    q_final          (6,) joint positions after `--probe-steps` deterministic steps from reset
    position_mm      (3,) |e| per axis there; orientation_deg (3,) |roll, pitch, yaw| of quat_err
    collide_frac     fraction of the probe's last half of steps that collided
    excess_rad       (6,) mean over those steps of how far the Gaussian mean lies past the
                     joint limits (the env clips it: no gradient, no exploration there)
    at_limit         (6,) fraction of those steps with the clipped action at a limit
    w_flips          sign changes of quat_err's w along the probe's last half
    log_std          (6,) the policy's log standard deviation

and at the end the paper's evaluation per seed (10 episodes, 5 mm stop) and the hold
(run to the horizon, error at the last step).

    python benchmarks/orientation_study.py --tasks MARAOrient MARACollisionOrient \
        --seeds 0 1 2 3 --variants baseline quat bound quat_bound --out study.json
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import shlex
import time

import jax
import jax.numpy as jnp
import numpy as np

import mara_mjx
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import make_evaluate
from mara_mjx.ppo.members import make_seed_trainer, take_seed
from mara_mjx.ppo.policy import make_policy
from mara_mjx.ppo.presets import PRESETS, default_preset
from mara_mjx.ppo.train import make_train

VARIANTS = {
    "default": {},  # the current default preset
    # the default preset before the orientation fixes (commit c6cf3b4)
    "baseline": {
        "init_log_std": 0.0,
        "canonical_quat": False,
        "bound_coef": 0.0,
        "train_collision_penalty": 0.0,
        "train_reward": "",
    },
    "quat": {
        "canonical_quat": True,
        "bound_coef": 0.0,
        "train_collision_penalty": 0.0,
        "init_log_std": 0.0,
        "train_reward": "",
    },
    "bound": {
        "bound_coef": 1.0,
        "canonical_quat": False,
        "train_collision_penalty": 0.0,
        "init_log_std": 0.0,
        "train_reward": "",
    },
    "quat_bound": {
        "canonical_quat": True,
        "bound_coef": 1.0,
        "train_collision_penalty": 0.0,
        "init_log_std": 0.0,
        "train_reward": "",
    },
    # orientation weighted more during the first half of training, then the env's reward
    "curr_half": {
        "canonical_quat": True,
        "bound_coef": 1.0,
        "train_reward": "beta=0.5,gamma=0.1",
        "train_reward_until": 0.5,
        "train_collision_penalty": 0.0,
        "init_log_std": 0.0,
    },
    "curr_full": {
        "canonical_quat": True,
        "bound_coef": 1.0,
        "train_reward": "beta=0.5,gamma=0.1",
        "train_reward_until": 1.0,
        "train_collision_penalty": 0.0,
        "init_log_std": 0.0,
    },
    # collisions penalised (as in the Collision tasks) during the first half of training
    "coll_half": {
        "canonical_quat": True,
        "bound_coef": 1.0,
        "train_collision_penalty": 1.0,
        "train_reward_until": 0.5,
        "init_log_std": 0.0,
        "train_reward": "",
    },
    "coll_half_std": {
        "canonical_quat": True,
        "bound_coef": 1.0,
        "train_collision_penalty": 1.0,
        "train_reward_until": 0.5,
        "init_log_std": -1.0,
        "train_reward": "",
    },
    "curr_half_nobound": {
        "canonical_quat": True,
        "bound_coef": 0.0,
        "train_collision_penalty": 0.0,
        "init_log_std": 0.0,
        "train_reward": "beta=0.5,gamma=0.1",
        "train_reward_until": 0.5,
    },
}


def parse_variant(name: str) -> dict:
    """A name from VARIANTS, or 'key=value;key=value' PPOConfig overrides (JSON values)."""
    if name in VARIANTS:
        return VARIANTS[name]
    out = {}
    for part in name.split(";"):
        k, v = part.split("=", 1)
        value = json.loads(v)
        out[k] = tuple(value) if isinstance(value, list) else value  # tuple fields
    return out


def make_probe(env, probe_steps: int, episodes: int = 4):
    lower, upper = jnp.asarray(env.joint_lower), jnp.asarray(env.joint_upper)
    params = env.make_params(reset_noise=0.02)
    keys = jax.random.split(jax.random.key(12345), episodes)
    quat = [p["start"] for p in env.observation_layout if p["name"] == "quat_err"] or None

    def probe(policy):
        state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

        def body(state, _):
            mean = policy(state.obs)
            nxt = jax.vmap(env.step)(state, mean)
            clipped = jnp.clip(mean, lower, upper)
            rec = {
                "collided": nxt.metrics["collided"].astype(jnp.float32),
                "excess": jax.nn.relu(mean - upper) + jax.nn.relu(lower - mean),
                "at_limit": ((clipped <= lower + 1e-4) | (clipped >= upper - 1e-4)).astype(
                    jnp.float32
                ),
                "w": nxt.obs[:, quat[0]] if quat else jnp.zeros(episodes),
            }
            return nxt, rec

        state, rec = jax.lax.scan(body, state, None, probe_steps)
        half = probe_steps // 2
        tail = jax.tree.map(lambda x: x[half:], rec)
        w_sign = jnp.sign(tail["w"])
        return {
            "q_final": state.obs[:, :6].mean(0),
            "position_mm": 1000 * state.metrics["position_error"].mean(0),
            "orientation_deg": jnp.degrees(state.metrics["orientation_error"]).mean(0),
            "collide_frac": tail["collided"].mean(),
            "excess_rad": tail["excess"].mean((0, 1)),
            "at_limit": tail["at_limit"].mean((0, 1)),
            "w_flips": jnp.sum(w_sign[1:] != w_sign[:-1], axis=0).mean().astype(jnp.float32),
        }

    return probe


def save_seed_params(root: str, task: str, variant: str, seed: int, seed_state, config) -> None:
    """Pickle one seed's (params, obs_stats, config dict) under root/<task>_<variant>/seed<s>.pkl
    for offline analysis (random_target_study.load_saved_policy reads it back)."""
    name = "".join(c if c.isalnum() or c in "._-" else "_" for c in f"{task}_{variant}")
    folder = os.path.join(root, name)
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, f"seed{seed}.pkl"), "wb") as f:
        pickle.dump(jax.device_get((seed_state.params, seed_state.obs_stats, config.to_dict())), f)


def seed_row(stop: dict, hold: dict) -> dict:
    """One seed's paper evaluation (`stop`, make_evaluate's output for its 10 episodes)
    and hold (the same episodes to the horizon) as the studies' JSON rows record them."""
    return {
        "position_mm": np.mean(stop["position_error_mm"], 0).tolist(),
        "orientation_deg": np.mean(stop["orientation_error_deg"], 0).tolist(),
        "reached": int(np.sum(stop["reached"])),
        "collisions": float(np.mean(stop["collisions"])),
        "hold_position_mm": np.mean(hold["position_error_mm"], 0).tolist(),
        "hold_orientation_deg": np.mean(hold["orientation_error_deg"], 0).tolist(),
        "hold_collisions_per_episode": float(np.mean(hold["collisions"])),
    }


def study(task: str, variant: str, seeds: tuple[int, ...], args) -> dict:
    t0 = time.monotonic()
    env = mara_mjx.make(task)
    overrides = parse_variant(variant)
    sizes = {"num_envs": 16, "num_steps": 8, "num_minibatches": 4} if args.tiny else {}
    if args.total_timesteps:
        sizes["total_timesteps"] = args.total_timesteps
    preset = default_preset(task) if args.preset == "task" else args.preset
    config = PRESETS[preset].replace(**{**sizes, **overrides})  # variant wins
    trainer = make_train(env, config, updates_per_call=args.chunk, devices=1)
    config = trainer.config
    st = make_seed_trainer(trainer, seeds)
    probe = jax.jit(jax.vmap(make_probe(env, args.probe_steps)))
    ev = make_evaluate(env, EvalConfig())
    hold = make_evaluate(env, EvalConfig(tolerance_mm=0.0))
    ev_all, hold_all = jax.jit(jax.vmap(ev)), jax.jit(jax.vmap(hold))

    state = st.init()
    done, timeline, det = 0, [], []
    first = {}
    while done < trainer.num_updates:
        n = min(args.chunk, trainer.num_updates - done)
        state, metrics = st.run(state, n)
        metrics = jax.device_get(metrics)
        done += n
        now = time.monotonic() - t0
        det_err = np.asarray(metrics["det_error_mm"])[:, :n]  # (S, n)
        det.append(det_err)
        for thr in (5.0, 1.0):
            for i, s in enumerate(seeds):
                if (thr, s) not in first and np.nanmin(det_err[i]) < thr:
                    first[(thr, s)] = {"time_s": now, "update": done}
        policy = make_policy(state, config)
        p = jax.device_get(probe(policy))
        log_std = np.asarray(state.params["params"]["log_std"])
        timeline.append(
            {
                "update": done,
                "env_steps": done * trainer.steps_per_update,
                "time_s": now,
                **{k: np.asarray(v).tolist() for k, v in p.items()},
                "log_std": log_std.tolist(),
                "entropy": np.asarray(metrics["entropy"])[:, n - 1].tolist(),
            }
        )
    train_s = time.monotonic() - t0
    policy = make_policy(state, config)
    evals = jax.device_get(ev_all(policy))
    holds = jax.device_get(hold_all(policy))
    per_seed = []
    for i, s in enumerate(seeds):
        if args.save_params:
            save_seed_params(args.save_params, task, variant, s, take_seed(state, i), config)
        per_seed.append(
            {
                "seed": s,
                **seed_row(
                    jax.tree.map(lambda x: x[i], evals), jax.tree.map(lambda x: x[i], holds)
                ),
                "time_to_5mm_s": first.get((5.0, s), {}).get("time_s"),
                "time_to_1mm_s": first.get((1.0, s), {}).get("time_s"),
            }
        )
    out = {
        "task": task,
        "variant": variant,
        "preset": preset,
        "overrides": overrides,
        "config": config.to_dict(),
        "seeds": list(seeds),
        "train_s": train_s,
        "env_steps_per_s": len(seeds) * trainer.num_updates * trainer.steps_per_update / train_s,
        "per_seed": per_seed,
        "timeline": timeline,
    }
    print(f"== {task} {variant}: {train_s:.0f} s", flush=True)
    for r in per_seed:
        print(
            f"  seed {r['seed']}: pos {np.round(r['position_mm'], 2).tolist()} mm, "
            f"ori {np.round(r['orientation_deg'], 2).tolist()} deg, reached {r['reached']}/10, "
            f"hold ori {np.round(r['hold_orientation_deg'], 2).tolist()}, "
            f"coll/ep {r['hold_collisions_per_episode']:.0f}, 1mm at {r['time_to_1mm_s']}",
            flush=True,
        )
    last = timeline[-1]
    print(f"  excess {np.round(last['excess_rad'], 3).tolist()}", flush=True)
    print(f"  at_limit {np.round(last['at_limit'], 2).tolist()}", flush=True)
    print(f"  w_flips {last['w_flips']}, collide {np.round(last['collide_frac'], 2).tolist()}")
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tasks", nargs="+", default=["MARAOrient", "MARACollisionOrient"])
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS))
    p.add_argument(
        "--preset",
        default="default",
        choices=["task", *sorted(PRESETS)],
        help="the PPO preset the variants change; 'task': the train CLI's for each task",
    )
    p.add_argument("--total-timesteps", type=int, default=0)
    p.add_argument("--chunk", type=int, default=20)
    p.add_argument("--probe-steps", type=int, default=60)
    p.add_argument("--tiny", action="store_true", help="CPU smoke test sizes")
    p.add_argument("--save-params", default="", help="folder: each seed's params, pickled")
    p.add_argument("--out", default="orientation_study.json")
    args = p.parse_args()
    run_studies(study, args, "orientation_study.py")


def run_studies(study, args, script: str, **extra) -> None:
    """study(task, variant, seeds, args) for every (task, variant), rewriting args.out
    after each, with the command, device and versions."""
    results = []
    for task in args.tasks:
        for variant in args.variants:
            results.append(study(task, variant, tuple(args.seeds), args))
            with open(args.out, "w") as f:
                json.dump(
                    {
                        "command": f"python benchmarks/{script} " + shlex.join(os.sys.argv[1:]),
                        "device": str(jax.devices()[0]),
                        "jax": jax.__version__,
                        **extra,
                        "results": results,
                    },
                    f,
                )


if __name__ == "__main__":
    main()
