"""Choose the contact pairs of assets/mara.xml from data, not by guesswork.

MJX tests every listed contact pair in every step, so each pair costs throughput.
This script lists every pair the spec calls a collision (robot vs table, robot
bodies not joined by a joint; not the base resting on the table), samples joint
configurations uniformly inside the joint limits, runs C MuJoCo's collision
detection with all of them, and keeps a greedy minimal set of pairs that flags
exactly the same configurations as colliding (a set cover). Pairs that never
touch, or only ever touch while another kept pair also touches, are dropped:
the `collided` flag the tasks use is unchanged on the sample.

    python benchmarks/contact_pairs.py --samples 200000

prints the <pair> lines to paste into the <contact> block, with the coverage.
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np

from mara_mjx.envs.arm import XML_PATH as XML
from mara_mjx.envs.arm import candidate_pairs, with_pairs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=200_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    base = mujoco.MjModel.from_xml_path(str(XML))
    cands = candidate_pairs(base)
    model = mujoco.MjModel.from_xml_string(with_pairs(XML.read_text(), cands))
    data = mujoco.MjData(model)
    index = {frozenset(p): k for k, p in enumerate(cands)}

    rng = np.random.default_rng(args.seed)
    lo, hi = model.jnt_range[:, 0], model.jnt_range[:, 1]
    hits = np.zeros((args.samples, len(cands)), bool)
    for i in range(args.samples):
        data.qpos[:] = rng.uniform(lo, hi)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        for c in data.contact[: data.ncon]:
            if c.dist < 0:
                pair = frozenset((model.geom(c.geom1).name, model.geom(c.geom2).name))
                hits[i, index[pair]] = True

    colliding = hits.any(1)
    chosen: list[int] = []
    covered = np.zeros(args.samples, bool)
    while True:
        gain = (hits & ~covered[:, None]).sum(0)
        k = int(gain.argmax())
        if gain[k] == 0:
            break
        chosen.append(k)
        covered |= hits[:, k]
    print(f"{len(cands)} candidate pairs, {int((hits.sum(0) > 0).sum())} ever touch")
    print(f"colliding configurations: {colliding.mean():.4f} of {args.samples}")
    print(f"kept {len(chosen)} pairs; configurations missed: {int((colliding & ~covered).sum())}")
    for k in chosen:
        a, b = cands[k]
        print(f'    <pair geom1="{a}" geom2="{b}"/>  <!-- {hits[:, k].sum()} hits -->')


if __name__ == "__main__":
    main()
