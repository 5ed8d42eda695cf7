"""The `peers` study: C MuJoCo (all CPU cores) against MJX on the same model.

At each of `sizes` env counts. Train driver: C MuJoCo mj_kinematics + mj_collision for
random joint targets in one process per CPU core (`mara_mjx.bench.cpeer`) against the
env study's timing of the MJX train driver.
Real driver: C side, `mujoco.rollout.rollout` (nthread = os.cpu_count(), one MjData per
thread, persistent thread pool) of N arms x `steps` env steps x 10 substeps of mj_step
(5 ms, implicitfast, Newton, the model's contacts and position+velocity servos), open
loop, with the controls the real driver would send: per env step uniform random joint
targets, the servo reference moving toward them at `velocity` rad/s, ctrl = [ref,
ref_vel] (built in numpy beforehand, not timed). MJX side: the `env` study's timing of
`BatchedEnv.step` with the real driver solving contacts as C does (MARA task,
real_contacts='physical'; the default only detects them) for the same N and steps, which
does the same 10 mjx.step substeps plus what C rollout does not: the final kinematics +
collision for the pose, observation, reward, penetration checks and auto-reset. So the
ratio MJX / C slightly favours C. Reported: env steps/s and physics steps/s (env steps x
10) of both, and MJX / C (env steps/s ratio) on the MJX row. `skip_mjx` times the C
sides only (the MJX real-driver compile takes about 35 s on a CPU). The PPO peer is the
`brax` study.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from typing import Any, ClassVar, Literal

import numpy as np

import mara_mjx
from mara_mjx.bench.env import DRIVERS, time_env
from mara_mjx.bench.runner import BenchConfig, Study, device_info, fmt_m


@dataclasses.dataclass(frozen=True)
class PeersConfig(BenchConfig):
    """The peers study's settings."""

    drivers: tuple[Literal["train", "real"], ...] = ("train", "real")
    """Drivers whose work is compared."""
    sizes: tuple[int, ...] = (256, 1024, 4096)
    """Environment counts (C rollout and MJX)."""
    skip_mjx: bool = False
    """Time the C side only (the MJX real-driver compile takes ~35 s on a CPU)."""
    steps: int = 100
    """Env steps per timed call."""
    repeats: int = 5
    """Timed calls after the first."""

    QUICK: ClassVar[dict[str, Any]] = {"sizes": (4,), "steps": 4, "repeats": 1}
    POSITIVE: ClassVar[tuple[str, ...]] = ("sizes", "steps", "repeats")
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"drivers": DRIVERS}


def c_rollout_inputs(
    env: Any, num_envs: int, steps: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Initial states (num_envs, nstate) and controls (num_envs, steps * substeps, 12)
    for `mujoco.rollout` equivalent to the MJX real driver: each env step draws uniform
    joint targets in the joint box; over its `n_substeps` physics steps the servo
    reference moves toward them at `velocity` rad/s, ctrl = [ref (6), ref_vel (6)]
    as in `Arm.real_step`. The arm starts at rest at q = 0."""
    import mujoco

    m = env.arm.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, state0, spec)
    rng = np.random.default_rng(seed)
    dt, n_sub = env.arm.timestep, env.n_substeps
    max_move = env.config.velocity * dt
    ref = np.zeros((num_envs, 6))
    ctrl = np.empty((num_envs, steps * n_sub, 12))
    for t in range(steps):
        command = rng.uniform(env.joint_lower, env.joint_upper, (num_envs, 6))
        for k in range(n_sub):
            move = np.clip(command - ref, -max_move, max_move)
            ref = ref + move
            ctrl[:, t * n_sub + k, :6] = ref
            ctrl[:, t * n_sub + k, 6:] = move / dt
    return np.tile(state0, (num_envs, 1)), ctrl


def time_c_rollout(
    env: Any, num_envs: int, steps: int, repeats: int, nthread: int
) -> dict[str, Any]:
    """Steady-state env steps/s of C MuJoCo `mujoco.rollout.rollout` on `nthread` CPU
    threads (one MjData each) for `num_envs` arms x `steps` env steps (x substeps)."""
    import mujoco
    from mujoco import rollout

    m = env.arm.mj_model
    datas = [mujoco.MjData(m) for _ in range(nthread)]
    state0, ctrl = c_rollout_inputs(env, num_envs, steps)
    nstep = ctrl.shape[1]
    state_out = np.empty((num_envs, nstep, state0.shape[1]))
    sensor_out = np.empty((num_envs, nstep, m.nsensordata))

    def call() -> float:
        t0 = time.perf_counter()
        rollout.rollout(
            m,
            datas,
            state0,
            ctrl,
            control_spec=mujoco.mjtState.mjSTATE_CTRL,
            state=state_out,
            sensordata=sensor_out,
            persistent_pool=True,
        )
        return time.perf_counter() - t0

    first = call()
    median = statistics.median(call() for _ in range(repeats))
    sps = num_envs * steps / median
    return {
        "impl": f"mujoco C rollout ({nthread} threads)",
        "device": f"cpu x{nthread}",
        "num_envs": num_envs,
        "steps_per_call": steps,
        "substeps": env.n_substeps,
        "first_call_s": first,
        "median_call_s": median,
        "env_steps_per_s": sps,
        "physics_steps_per_s": sps * env.n_substeps,
        "collision_fraction": None,
        "mjx_over_c": None,
    }


def peers_study(args: PeersConfig) -> list[dict[str, Any]]:
    """C MuJoCo vs MJX, same env counts, same run: the train driver's work (kinematics +
    collision, `mara_mjx.bench.cpeer`) and the real driver's (`mujoco.rollout`); `--drivers`
    picks which."""
    import os

    from mara_mjx.bench.cpeer import KinematicsPool

    task = args.tasks[0]
    env = mara_mjx.make(task, driver="real")
    nthread = os.cpu_count() or 1
    records = []

    def compare(driver: str, n: int, c: dict[str, Any]) -> None:
        """Record C's timing `c` and (unless skip_mjx) MJX's for the same driver and n."""
        records.append(c)
        line = f"n={n:>7d} {driver} driver: C {c['env_steps_per_s'] / 1e6:8.3f} M/s"
        if not args.skip_mjx:
            solved = {"real_contacts": "physical"} if driver == "real" else {}
            mj = time_env(task, driver, n, args.steps, args.repeats, **solved)
            ratio = mj["env_steps_per_s"] / c["env_steps_per_s"]
            impl = f"mjx {driver} driver (BatchedEnv.step)"
            records.append(
                {"impl": impl, "device": device_info()["device_kind"], **mj, "mjx_over_c": ratio}
            )
            line += f"  MJX {mj['env_steps_per_s'] / 1e6:8.3f} M/s  MJX/C {ratio:.2f}x"
        print(line, flush=True)

    if "train" in args.drivers:
        pool = KinematicsPool(env.arm.mj_model, nthread)
        try:
            for n in args.sizes:
                compare("train", n, pool.time(n, args.steps, args.repeats))
        finally:
            pool.close()
    if "real" in args.drivers:
        for n in args.sizes:
            compare("real", n, time_c_rollout(env, n, args.steps, args.repeats, nthread))
    return records


TABLE: dict[str, Any] = {
    "title": "peers study: C MuJoCo (all CPU cores) vs MJX, train-driver and real-driver work",
    "columns": [
        ("implementation", lambda r: r["impl"]),
        ("device", lambda r: r["device"]),
        ("envs", lambda r: f"{r['num_envs']:,}"),
        ("env steps/s", lambda r: fmt_m(r["env_steps_per_s"])),
        ("physics steps/s", lambda r: fmt_m(r["physics_steps_per_s"])),
        (
            "MJX / C",
            lambda r: "" if r.get("mjx_over_c") is None else f"{r['mjx_over_c']:.2f}x",
        ),
    ],
    "series": lambda r: r["impl"],
    "style": lambda r: "-" if r["impl"].startswith("mjx") else "--",
}

STUDY = Study("peers", PeersConfig, peers_study, TABLE, "C MuJoCo (all cores) vs MJX")
