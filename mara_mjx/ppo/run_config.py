"""The configs of the host loop and of the accuracy evaluation (none of them changes what
`make_train` compiles): RunConfig (`python -m mara_mjx.train`'s output folder,
checkpoints, logging, jit granularity, seeds) and EvalConfig (the paper's evaluation:
10 episodes, the 5 mm stop condition). Both are re-exported by `mara_mjx.ppo.config`;
the train and evaluate CLIs generate their `--run.*` / `--eval.*` flags from them.
"""

from __future__ import annotations

import dataclasses
import math

from mara_mjx.config import ConfigMixin as _ConfigMixin
from mara_mjx.config import check_int as _check_int
from mara_mjx.config import check_range as _check_range


@dataclasses.dataclass(frozen=True)
class RunConfig(_ConfigMixin):
    """The host loop of `python -m mara_mjx.train` (none of it changes the results)."""

    out: str = ""
    """Run folder for logs, checkpoints and plots; '' means runs/<env>-<timestamp>."""
    checkpoint_every: int = 50
    """Write a checkpoint every this many updates (and at the end)."""
    keep_checkpoints: int = 3
    """Periodic checkpoints to keep (the newest); the final one is always kept."""
    updates_per_call: int = 10
    """PPO updates per jitted call (a lax.scan on device); the host logs all of them after
    each call, so wall-clock columns have this granularity."""
    devices: int = 0
    """Devices to spread the environments and the batch over (0 = all; see
    mara_mjx.runtime.sharding). num_envs and the minibatch size must be multiples of it; the
    results match one device up to floating-point reduction order."""
    progress: bool = True
    """Show a progress bar (tqdm, on stderr)."""
    tensorboard: bool = True
    """Write TensorBoard event files (tensorboardX) under <out>/tb."""
    evaluate: bool = True
    """At the end, run the accuracy evaluation (EvalConfig) and save eval.json."""
    plots: bool = True
    """At the end, save PNG plots of mean reward, policy entropy and error vs env steps."""
    seeds: int = 1
    """Independent runs in one jitted program (vmapped; spread over the devices, each
    seed's envs on one device): seeds ppo.seed .. ppo.seed + seeds - 1, each written to
    <out>/seed_<s>/ as a single run writes it, plus a summary across seeds
    (<out>/seeds.json, seeds.md)."""

    def __post_init__(self):
        if not isinstance(self.out, str):
            raise ValueError(f"out must be a path string, got {self.out!r}")
        _check_int("checkpoint_every", self.checkpoint_every, minimum=1)
        _check_int("keep_checkpoints", self.keep_checkpoints, minimum=1)
        _check_int("updates_per_call", self.updates_per_call, minimum=1)
        _check_int("devices", self.devices, minimum=0)
        if not (isinstance(self.seeds, int) and not isinstance(self.seeds, bool)) or self.seeds < 1:
            raise ValueError(
                f"seeds must be an int >= 1 (1: one run; N > 1: N seeds in one program), "
                f"got {self.seeds!r}"
            )
        for name in ("progress", "tensorboard", "evaluate", "plots"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")


@dataclasses.dataclass(frozen=True)
class EvalConfig(_ConfigMixin):
    """The paper's accuracy evaluation: the deterministic policy (the Gaussian mean) in
    `episodes` episodes, each stopped at the first step where every axis of the position
    error is within `tolerance_mm`, or at the horizon."""

    episodes: int = 10
    """Episodes, run in parallel; episode i resets from key split(key(seed), episodes)[i]."""
    noise: float = 0.02
    """Half-width (rad) of the uniform perturbation of the reset joint positions (the env's
    reset_noise) so that the episodes differ, as the paper's Gazebo runs did."""
    tolerance_mm: float = 5.0
    """Stop condition: every axis of |e| within this (mm); 0 runs to the horizon."""
    seed: int = 0
    """Seed of the episodes' reset keys."""
    rate_limit: bool = False
    """Real driver only: each action (clipped to the joint limits) is moved toward the
    observed joints, the whole joint displacement scaled by one factor, so that no joint
    is asked for more than the servos travel in one step, velocity x control_dt
    (mara_mjx.ppo.policy.rate_limited): the servos then follow the policy's direction in
    joint space instead of each saturating on its own, which turns a large step into a
    diagonal through joint space (benchmarks/NOTES.md section 25). The servos' reference
    starts from where they were commanded, not from the observed joints, so a lagging arm
    follows the direction only approximately. A deployment-side output stage of the
    policy, as a robot's trajectory scaling would be; the env is unchanged."""
    collision_guard_mm: float = -1.0
    """The evaluated policy's collision guard (PolicyConfig.collision_guard_mm, a
    deployed-only rule, so the same trained parameters): -1 as the checkpoint was trained
    (default), >= 0 replaces it (0: off), e.g. to judge existing checkpoints with it."""
    plan_steps: int = -1
    """The evaluated policy's imagined train-driver steps (PolicyConfig.plan_steps, a
    deployed-only rule, so the same trained parameters): -1 as the checkpoint was trained
    (default), >= 0 replaces it (0: off)."""
    plan_starts: int = -1
    """The evaluated policy's other starting postures of the plan (PolicyConfig.plan_starts,
    a deployed-only rule; needs plan_steps): -1 as the checkpoint was trained (default),
    >= 0 replaces it (0: off)."""
    commit_rad: float = -1.0
    """The evaluated policy's arrival tolerance for held commands (PolicyConfig.commit_rad,
    a deployed-only rule applied by the evaluation loop around the policy): -1 as the
    checkpoint was trained or the file exported (default), >= 0 replaces it (0: off)."""

    def __post_init__(self):
        _check_int("episodes", self.episodes, minimum=1)
        _check_int("seed", self.seed, minimum=0)
        _check_range("noise", self.noise, 0.0, 0.5)
        _check_range("tolerance_mm", self.tolerance_mm, 0.0, math.inf)
        if self.collision_guard_mm != -1.0:
            _check_range("collision_guard_mm", self.collision_guard_mm, 0.0, 100.0)
        from mara_mjx.ppo.parametrisation import check_overrides

        check_overrides(self.plan_steps, self.plan_starts, self.commit_rad)
