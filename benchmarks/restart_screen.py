"""Open-loop screen of the plan's restarts (PolicyConfig.plan_starts) for trained seeds of a
random-target Orient task: on the nominal arm, without contacts or servos, which share of
the held-out poses the policy's own plan reaches, and which share it or one of the first
K restarts reaches under the restarts' rule (a restart counts where it reaches and its
servos' path from the reset posture keeps PLAN_CLEAR_MM, policy.path_clearance at
PLAN_PATH_POINTS points), for several K, beside the share without the clearance check;
and at which poses, where the own first landing from the reset posture misses (a
restart is then taken at once), the restart the rule takes with the most starts comes
within 2 mm of a contact on a finer path (60 points), or a reaching restart that the rule
rejects exists (benchmarks/NOTES.md sections 48 and 49).

    python benchmarks/restart_screen.py RUN/seed_1398 RUN/seed_1404 [--ks 8 16 32]
        [--poses 1000] [--eval_seed 1000] [--json OUT.json]

Per seed: the own plan chained from the reset posture (q = 0) for 8 decisions of
plan_steps (16 if the checkpoint has none) imagined steps; each of start_postures(max K)
imagined for PLAN_START_STEPS; "reaches": within PLAN_KEEP_MM on every position axis and
in orientation (1 mm, 1 deg), the restarts' rule. The held-out poses are the evaluation's
(targets.evaluation_poses of eval_seed). A minute or two per seed on one CPU core.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

DECISIONS, CLOSE_MM, FINE_POINTS = 8, 2.0, 60


def screen(folder: Path, ks: list[int], poses: int, eval_seed: int) -> dict:
    from mara_mjx.envs import targets
    from mara_mjx.envs.clearance import clearance
    from mara_mjx.envs.task_space import nominal_chain
    from mara_mjx.ppo.parametrisation import (
        PLAN_CLEAR_MM,
        PLAN_KEEP_MM,
        PLAN_PATH_POINTS,
        PLAN_START_STEPS,
    )
    from mara_mjx.ppo.policy import (
        _observation,
        landing_error,
        load_policy,
        path_clearance,
        planned_landing,
        start_postures,
    )
    from mara_mjx.runtime import runs

    policy = load_policy(folder)
    steps = policy.config.policy.plan_steps or 16
    act = policy.one_step()
    env = runs.make_env(json.loads((folder / "config.json").read_text()))
    if not getattr(env.task, "orientation", False) or not hasattr(env, "region"):
        raise SystemExit(f"{folder}: not a random-target Orient task")
    held = targets.evaluation_poses(env.arm.mj_model, env.region, poses, eval_seed)
    tp, tq = (jnp.asarray(x, jnp.float32) for x in (held.pos, held.quat))
    tcp = jnp.vectorize(nominal_chain().tcp, signature="(6)->(3),(4)")

    def obs_at(q):
        pos, quat = tcp(q)
        return _observation(q, pos, quat, jnp.zeros_like(pos), tp, tq, True)

    def error(q):  # (..., poses, 6) -> (..., poses): the restarts' ranking
        return landing_error(q, tp, tq, True)

    land = jax.jit(lambda q, n: planned_landing(act, obs_at(q), n), static_argnums=1)
    start = time.perf_counter()
    q = jnp.zeros((poses, 6), jnp.float32)
    for i in range(DECISIONS):
        q = land(q, steps)
        if i == 0:  # the first decision: where it misses, a restart is taken at once
            first_miss = np.asarray(error(q)) > PLAN_KEEP_MM
    own_ok = np.asarray(error(q)) <= PLAN_KEEP_MM
    starts = start_postures(max(ks))
    lands = np.stack([np.asarray(land(jnp.broadcast_to(s, (poses, 6)), PLAN_START_STEPS))
                      for s in starts])  # fmt: skip
    errs = np.asarray(error(jnp.asarray(lands)))
    reach = errs <= PLAN_KEEP_MM  # (K, poses)
    zero = jnp.zeros((poses, 6), jnp.float32)
    need = min(PLAN_CLEAR_MM / 1000.0, float(clearance(zero[0])))  # (from the reset posture)
    rule_path = jax.jit(lambda q1: path_clearance(zero, q1, PLAN_PATH_POINTS))
    fine_path = jax.jit(lambda q1: path_clearance(zero, q1, FINE_POINTS))
    clear = np.stack([np.asarray(rule_path(jnp.asarray(x))) for x in lands]) >= need
    ok = reach & clear
    row = {"seed_folder": str(folder), "own": float(own_ok.mean())}
    for k in ks:
        row[f"K={k}"] = float((own_ok | ok[:k].any(0)).mean())
        row[f"K={k} without the clearance check"] = float((own_ok | reach[:k].any(0)).mean())
    miss = first_miss  # (the commit rule holds a restart taken at the first decision)
    spans = np.abs(lands).max(-1)  # (K, poses): the largest joint move from q = 0
    taken = np.where(ok, spans, np.inf).argmin(0)  # the rule's choice among max(ks) starts
    chosen = miss & ok.any(0)
    idx = np.nonzero(chosen)[0]
    fine = np.asarray(fine_path(jnp.asarray(lands[taken, np.arange(poses)])))
    row["poses_own_first_landing_misses"] = int(miss.sum())
    row["poses_a_restart_reaches"] = int((miss & reach.any(0)).sum())
    row["poses_a_clear_restart_reaches"] = int(chosen.sum())
    row["poses_a_reaching_restart_is_rejected"] = sorted(
        int(i) for i in np.nonzero(miss & (reach & ~clear).any(0))[0])  # fmt: skip
    row["poses_the_taken_restart_within_2mm_on_60_points"] = sorted(
        int(i) for i in idx[1000 * fine[idx] < CLOSE_MM])  # fmt: skip
    row["seconds"] = time.perf_counter() - start
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("seeds", nargs="+", type=Path, help="seed folders (RUN/seed_S)")
    p.add_argument("--ks", nargs="+", type=int, default=[8, 16, 32])
    p.add_argument("--poses", type=int, default=1000)
    p.add_argument("--eval_seed", type=int, default=1000)
    p.add_argument("--json", type=Path, help="also write the rows here (a new file)")
    args = p.parse_args(argv)
    rows = [screen(f, sorted(args.ks), args.poses, args.eval_seed) for f in args.seeds]
    print("| seed | own plan | " + " | ".join(f"own or one of {k} restarts" for k in args.ks)
          + " | first misses: a reaching restart rejected"
          + " | the taken one within 2 mm (60 points) |")  # fmt: skip
    print("|---" * (len(args.ks) + 4) + "|")
    for r in rows:
        cells = [f"{100 * r['own']:.1f}%"] + [
            f"{100 * r[f'K={k}']:.1f}% ({100 * r[f'K={k} without the clearance check']:.1f}%)"
            for k in args.ks
        ]
        print(f"| {Path(r['seed_folder']).name} | " + " | ".join(cells)
              + f" | {r['poses_a_reaching_restart_is_rejected']}"
              + f" | {r['poses_the_taken_restart_within_2mm_on_60_points']} |")  # fmt: skip
    if args.json:
        if args.json.exists():
            print(f"error: {args.json} exists; name a new file", file=sys.stderr)
            return 2
        args.json.write_text(json.dumps({"command": " ".join(sys.argv), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
