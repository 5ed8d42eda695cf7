"""Train an imitation student on for a few updates under other settings, from its
checkpoint (params and observation statistics into a fresh `make_train` state), and save
the result as a seed folder that `benchmarks/student_fixed_point.py` reads. A CPU probe
of what a setting does to a trained student (benchmarks/NOTES.md section 57), not a way
to train: the optimiser and the envs start afresh.

    python benchmarks/imitation_finetune.py STUDENT_SEED TEACHER_SEED MODE UPDATES OUT_SEED
    # MODE: floor (the student's own config), spread (--imitation_spread 0.05,
    # --reset_noise 0.02, floor 0.01), lookahead (spread and --imitation_lookahead 3
    # within 20 mm: NOTES section 59) or lookahead2 (the same with 2)
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax
import numpy as np

import mara_mjx
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.config import TrainConfig
from mara_mjx.ppo.teacher import load_teacher
from mara_mjx.ppo.train import make_train


def main() -> None:
    student, teacher_dir, mode, updates, out = sys.argv[1:6]
    updates = int(updates)
    if Path(out).exists():  # never write into a run's own folder
        raise SystemExit(f"error: {out} exists; name a new folder")
    jax.config.update("jax_default_matmul_precision", "highest")
    found = ckpt.find_checkpoint(student)
    arrays, meta = ckpt.load_checkpoint(found)
    config = TrainConfig.from_meta(meta)
    if mode not in ("floor", "spread", "lookahead", "lookahead2"):
        raise SystemExit(f"MODE {mode!r}: choose floor, spread, lookahead or lookahead2")
    env = mara_mjx.make(meta["env_name"], reset_noise=0.0 if mode == "floor" else 0.02)
    if mode != "floor":
        config = config.replace(log_std_floor=-4.6, imitation_spread=0.05)
    if mode.startswith("lookahead"):
        k = 2 if mode == "lookahead2" else 3
        config = config.replace(imitation_lookahead=k, imitation_lookahead_mm=20.0)
    batch = config.ppo.num_envs * config.ppo.num_steps
    config = config.replace(teacher=teacher_dir, total_timesteps=batch * updates)
    trainer = make_train(env, config, teacher=load_teacher(teacher_dir, meta["env_name"]))
    state = trainer.init(jax.random.key(7))
    state = state.replace(
        params=ckpt.arrays_to_state(arrays, state.params, "params/"),
        obs_stats=ckpt.arrays_to_state(arrays, state.obs_stats, "obs_stats/"),
    )
    start = time.time()
    for i in range(updates):
        state, metrics = trainer.run(state, 1)
        if i % 10 == 0:
            print(f"update {i}: loss {float(metrics['loss'][0]):.3f}, {time.time() - start:.0f} s")
    with np.load(found, allow_pickle=False) as z:  # the checkpoint, its policy replaced
        new = {k: z[k] for k in z.files}
    for prefix, tree in (("params/", state.params), ("obs_stats/", state.obs_stats)):
        for path, x in jax.tree_util.tree_flatten_with_path(tree)[0]:
            new[prefix + ckpt.leaf_name(path)] = np.asarray(x)
    (Path(out) / "checkpoints").mkdir(parents=True)
    np.savez(Path(out) / "checkpoints" / "ckpt_00000999.npz", **new)
    print(f"saved {out}")


if __name__ == "__main__":
    main()
