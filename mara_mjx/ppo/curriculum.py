"""Training-only shaping: what a run does while it trains and the saved policy never sees.

    CurriculumConfig   reward schedules (train_reward, train_reset_noise, fading by
                       train_reward_until), penalties (collisions, joint limits, the
                       mean outside the joint box, a margin from contacts), an orientation
                       bonus, staggered first episodes, a share of envs at a servo's pace,
                       population-based training, and the reach probe (a measurement of
                       the saved policy during training)
    resolve(curriculum, env) -> the config with what `env` cannot apply cleared
    make_schedule(curriculum, env, benv, num_updates) -> Schedule: the functions
                       `mara_mjx.ppo.train.make_train` calls (the rollout's env params,
                       the first episodes, the shaped reward)
    capped_envs(curriculum, num_envs) -> the servo-paced share's action cap, or None

It is `TrainConfig.curriculum` (`mara_mjx.ppo.config`), never read by the evaluation, the
saved policy or the exported file. Flags: `--train_reward`, `--population`, ... (also
`--ppo.population`); the population's exploit step: `mara_mjx.ppo.members.population`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from mara_mjx.config import ConfigMixin as _ConfigMixin
from mara_mjx.config import check_int as _check_int
from mara_mjx.config import check_range as _check_range
from mara_mjx.envs.rewards import check_reward_value, collision_penalty
from mara_mjx.runtime import sharding


@dataclasses.dataclass(frozen=True)
class CurriculumConfig(_ConfigMixin):
    """Training-only shaping; every field's default is off. See `PRESETS` for the
    measured combinations. No preset sets orientation_bonus (and its two scales) or
    population (and exploit_*); they stay for the recorded studies that use them
    (NOTES sections 18 and 20) and the robustness study's "default --population 4"."""

    train_reward: str = ""
    """Curriculum over the env's reward hyperparameters during training only, e.g.
    'beta=0.5,gamma=0.1': the rollouts start with these values and move linearly to the
    env's own by `train_reward_until` of the updates (the evaluation always uses the env's
    own reward). '' is off. Names: the fields of mara_mjx.envs.rewards.RewardParams."""
    train_reward_until: float = 0.5
    """Fraction of the updates after which `train_reward` has reached the env's values
    (and `train_collision_penalty` has reached 0)."""
    train_reset_noise: float = 0.0
    """Training only: the rollouts' episodes start at the env's reset pose plus uniform
    joint noise of this half-width (rad, at most 0.5), shrinking linearly to the env's own
    `reset_noise` (or train_reset_noise_final) by `train_reward_until` of the updates, so
    early exploration sees the arm from many postures (evaluation keeps the env's reset).
    0 is off; ignored for an env without `reset_noise` in its params."""
    train_reset_noise_final: float = -1.0
    """What `train_reset_noise` (> 0) shrinks to (rad; -1: the env's own `reset_noise`).
    Equal to it: that noise for the whole training (0.02: the paper evaluation's starts)."""
    stagger_episodes: bool = False
    """Training only: each environment's first episode starts at a uniformly random step
    of the horizon (its step counter drawn in [0, max_episode_steps)), so the first
    episodes end at different times and every rollout mixes reaching and holding states.
    Without it all num_envs episodes start, and restart, together: a rollout of num_steps
    then holds one phase of the episode only (the reach from the reset pose in one update
    of every max_episode_steps / num_steps), measured in benchmarks/NOTES.md section 19.
    The first episodes are cut short (truncated: GAE bootstraps through them). Ignored for
    an env whose state has no `step` counter."""
    orientation_bonus: float = 0.0
    """Training only: add w exp(-d / orientation_bonus_distance) exp(-theta /
    orientation_bonus_angle) to every non-colliding step's reward (d the RMS position
    error, theta the orientation angle; w this value, in the env's reward units, whose
    maximum is 10), for the whole training. The env's own reward weighs one millimetre of
    position like about 200 degrees of orientation near the goal (benchmarks/NOTES.md
    section 20); this term's maximiser is the same exact pose and its slope in theta is
    w / orientation_bonus_angle there. 0 is off; cleared for an env without quat_err in
    its observation (the orientation is then not part of the task)."""
    orientation_bonus_angle: float = 0.1
    """rad: the angle scale of `orientation_bonus`."""
    orientation_bonus_distance: float = 0.005
    """m: the distance scale of `orientation_bonus` (the bonus fades in as the position
    converges)."""
    train_limit_penalty: float = 0.0
    """Training only: subtract w sum_j relu(|q_j - c_j| - f h_j) / ((1 - f) h_j) from
    every step's reward (q the observed joints at the step's start, c_j and h_j the
    centre and half-range of joint j's limits, f = `train_limit_soft`; each joint's term
    is 0 inside the soft range and 1 at its limit; legged_gym's dof_pos_limits), moving
    linearly to 0 by `train_reward_until` like the other curricula. Against policies that
    settle with a joint pinned at its limit, which leaves the wrist too few degrees of
    freedom for the orientation (benchmarks/NOTES.md section 23: every random-target
    policy held joint 4 at +-pi). 0: off; ignored for an env without joint limits."""
    train_limit_soft: float = 0.9
    """The fraction f of each joint's half-range inside which `train_limit_penalty` is 0."""
    train_collision_penalty: float = 0.0
    """Training only: subtract this times the spec's collision penalty C (delta (2 min(d,
    0.5))^eta, the env's delta and eta) from every colliding step's reward, moving linearly
    to 0 by `train_reward_until` of the updates; on top of the env's own penalty where the
    task has one. 0 is off."""
    train_clearance_penalty: float = 0.0
    """Training only, for the whole training: subtract w relu(1 - c / m) from every step's
    reward (w this value, in the env's reward units; m = `train_clearance_mm`; c the
    smallest clearance on the way the step moves the arm: the smallest signed distance of
    the env's contact pairs on the nominal arm, envs/clearance.clearance, at
    `train_clearance_points` evenly spaced postures on the way (`train_clearance_path`)
    from the observed posture to the one the step lands in, the landing included): 0 beyond the
    margin, w at contact. The train driver checks contact exactly and only where a step
    lands, so a path 0.1 mm above the table, or one whose jump sweeps through it, is as
    good as one 5 cm above it; a servo-driven arm moves along that line and touches on a
    millimetre of tracking error (benchmarks/NOTES.md sections 38-39: the real-driver
    collisions of `default --randomize`). The judged env is unchanged. MARA arms (q first
    in the observation, 6 joints). 0: off."""
    train_clearance_mm: float = 10.0
    """mm: the margin m of `train_clearance_penalty`."""
    train_clearance_points: int = 8
    """Postures checked per step by `train_clearance_penalty` (1: the landing only)."""
    train_clearance_path: str = "servo"
    """The way between the observed posture and the landing that `train_clearance_penalty`
    checks: 'servo', the real driver's reference (every joint at the same speed until it
    arrives, spec section 5: q + clip(dq, -s, s) for s up to max |dq|), or 'line', the
    straight joint-space line (the deployed rate limit's, EvalConfig.rate_limit, and a
    synchronised trajectory controller's)."""
    train_capped_fraction: float = 0.0
    """Training only: this fraction of the rollout's envs (the last ones) move each joint at
    most `train_capped_step` rad per step toward the sampled target, the way a servo
    moves (q + clip(a - q, -c, c) of the observed joints), instead of the train driver's
    jump; the others jump as before. A policy trained on jumps alone never sees the
    postures a servo-driven arm passes through on the way, and has fixed points there
    that stop it hundreds of millimetres short on the real driver (benchmarks/NOTES.md
    section 39). The deployed policy is unchanged. 0: off."""
    train_capped_step: float = 0.025
    """rad per step of `train_capped_fraction` (0.025: 0.5 rad/s at a 0.05 s control
    period, the real driver's default speed)."""
    bound_coef: float = 0.0
    """Weight of a loss that keeps the Gaussian mean inside the env's joint box:
    bound_coef * E[sum_j relu(mean_j - upper_j)^2 + relu(lower_j - mean_j)^2] (rad^2).
    The env clips actions to the joint limits, so a mean past a limit gets no gradient
    from the PPO loss and its noise no longer explores (rl_games' bounds loss)."""
    population: int = 1
    """Members trained side by side per run (vmapped; population-based training's exploit
    step, trainer-side): after the jitted call (RunConfig.updates_per_call) that crosses
    each `exploit_every` of the updates, and after the last update, the members are ranked
    by their mean training reward per step since the previous exploit, the worst
    `exploit_fraction` of them take over the params, optimiser state, observation
    statistics and env states of the best, and the best moves to member 0, whose policy is
    the run's (checkpoints, evaluation, export). Each member keeps its own PRNG stream, so
    copies diverge. A run whose early exploration commits to an arm posture from which the
    target pose is out of reach is replaced by one that did not (benchmarks/NOTES.md,
    section 18). 1 is off; total_timesteps counts per member."""
    exploit_every: float = 0.1
    """With population > 1: fraction of the updates between exploit steps."""
    exploit_fraction: float = 0.5
    """With population > 1: fraction of the members (rounded down, at least 1) replaced by
    copies of the best at each exploit step."""
    probe_reach_steps: int = 0
    """> 0: every jitted call of the trainer ends with a deterministic rollout of the
    policy training saves from the env's reset (`mara_mjx.ppo.metrics.reach_probe`: 4
    episodes, reset noise 0.02 rad as the paper's evaluation, this many steps; the train
    CLI's single runs compile it as its own program beside `run`: `make_train`'s
    probe_apart); the mean per-axis |e| at
    its last step is the metric `reach_error_mm` (the call's last update's row), which the
    time-to-accuracy records then use instead of `det_error_mm`. The one-step probe of
    `det_error_mm` starts where the sampled policy left each env and cannot show a
    deployed rule that takes several steps (ik_orient_first holds the TCP 1 cm off until
    the tool is aligned: benchmarks/NOTES.md section 28; for the Orient tasks' time to
    accuracy the orient_first preset sets 100). No effect on training; det_* then
    measure the training network's mean (`run` without the saved policy's forward). With
    `population`, member 0's probe before the call's exploit step (as its other metrics). 0: off."""
    teacher: str = ""
    """Imitation instead of reward: a run (folder or checkpoint) of the same task whose
    deployed policy this run learns on the states it visits (`mara_mjx.ppo.teacher`); with
    --seeds, a teacher run of several seeds teaches seed s its seed s. '' is off."""
    imitation_spread: float = 0.0
    """With teacher: the rollouts' noise, env i of N at least imitation_spread * i / (N - 1)
    rad (`mara_mjx.ppo.teacher.rollout_sigma`): states from the teacher's path to well
    off it; the loss keeps the student's own sigma. 0 is off."""
    imitation_lookahead: int = 1
    """With teacher: near the target, a state's label is the teacher's command up to
    imitation_lookahead - 1 steps later, not its next one (`mara_mjx.ppo.teacher.
    lookahead_action`): as far ahead as the TCP of this state and of the teacher's next
    states stays within imitation_lookahead_mm of the target, no episode ends and no step
    collides.
    A teacher whose last approach is a rule that stops and then jumps (orient_first's)
    is discontinuous there, and a student regressing across it approaches slowly
    (benchmarks/NOTES.md section 58); its destination is not. 1 is off."""
    imitation_lookahead_mm: float = 20.0
    """The radius (mm, TCP to target) within which imitation_lookahead acts (unused when
    it is 1)."""

    def __post_init__(self):
        _check_range("bound_coef", self.bound_coef, 0.0, math.inf)
        _check_range("train_reward_until", self.train_reward_until, 0.0, 1.0, low_open=True)
        _check_range("train_collision_penalty", self.train_collision_penalty, 0.0, math.inf)
        _check_range("orientation_bonus", self.orientation_bonus, 0.0, math.inf)
        _check_range("train_limit_penalty", self.train_limit_penalty, 0.0, math.inf)
        _check_range("train_clearance_penalty", self.train_clearance_penalty, 0.0, math.inf)
        _check_range("train_clearance_mm", self.train_clearance_mm, 0.0, 100.0, low_open=True)
        _check_int("train_clearance_points", self.train_clearance_points, minimum=1)
        _check_range("train_capped_fraction", self.train_capped_fraction, 0.0, 1.0)
        _check_range("train_capped_step", self.train_capped_step, 0.0, math.pi, low_open=True)
        if self.train_clearance_path not in ("servo", "line"):
            raise ValueError(
                f"train_clearance_path={self.train_clearance_path!r}: choose 'servo' or 'line'"
            )
        _check_range("train_limit_soft", self.train_limit_soft, 0.0, 0.99)
        _check_range(
            "orientation_bonus_angle", self.orientation_bonus_angle, 0.0, math.pi, low_open=True
        )
        _check_range(
            "orientation_bonus_distance", self.orientation_bonus_distance, 0.0, 1.0, low_open=True
        )
        _check_range("train_reset_noise", self.train_reset_noise, 0.0, 0.5)
        if (end := self.train_reset_noise_final) != -1.0 and not 0.0 <= end <= 0.5:
            raise ValueError(f"train_reset_noise_final={end!r}: -1 (the env's own) or in [0, 0.5]")
        reward_curriculum(self.train_reward)
        _check_int("population", self.population, minimum=1)
        _check_range("exploit_every", self.exploit_every, 0.0, 1.0, low_open=True)
        _check_range("exploit_fraction", self.exploit_fraction, 0.0, 1.0, low_open=True)
        _check_int("probe_reach_steps", self.probe_reach_steps, minimum=0)
        if not isinstance(self.teacher, str):
            raise ValueError(f"teacher must be a path string ('' for none), got {self.teacher!r}")
        _check_range("imitation_spread", self.imitation_spread, 0.0, math.pi)
        if self.imitation_spread > 0.0 and not self.teacher:
            raise ValueError("imitation_spread widens an imitation run's rollouts: give "
                             "--teacher RUN, or set imitation_spread 0")  # fmt: skip
        _check_int("imitation_lookahead", self.imitation_lookahead, minimum=1)
        if self.imitation_lookahead > 1 and not self.teacher:
            raise ValueError("imitation_lookahead labels an imitation run's states: give "
                             "--teacher RUN, or set imitation_lookahead 1")  # fmt: skip
        _check_range(
            "imitation_lookahead_mm", self.imitation_lookahead_mm, 0.0, 1000.0, low_open=True
        )
        if self.teacher and self.population > 1:  # the exploit step ranks by reward
            raise ValueError("teacher (imitation) and population > 1 do not combine")
        if not isinstance(self.stagger_episodes, bool):
            raise ValueError(
                f"stagger_episodes must be true or false, got {self.stagger_episodes!r}"
            )


def reward_curriculum(text: str) -> dict[str, float]:
    """'beta=0.5,gamma=0.1' -> {'beta': 0.5, 'gamma': 0.1}; ValueError naming the problem."""
    from mara_mjx.envs.rewards import RewardParams

    if not isinstance(text, str):
        raise ValueError(f"train_reward must be a string such as 'beta=0.5', got {text!r}")
    valid = [f.name for f in dataclasses.fields(RewardParams)]
    out: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = part.partition("=")
        name = name.strip()
        if not sep or name not in valid:
            raise ValueError(f"train_reward: {part!r} is not NAME=VALUE with NAME one of {valid}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"train_reward: {name}={value!r} is not a number") from None
        if not math.isfinite(number) or number < 0:
            raise ValueError(f"train_reward: {name}={value!r} must be a finite number >= 0")
        out[name] = number
    return out


def resolve(curriculum: CurriculumConfig, env: Any) -> CurriculumConfig:
    """`curriculum` for `env`: `train_reward` and `train_collision_penalty` cleared for an
    env whose params have no `reward` (a user's own Env: the preset's defaults cannot
    apply to it, and the saved config says so), `train_reset_noise` for one without
    `reset_noise`, `orientation_bonus` for one without quat_err in its observation;
    ValueError for train_clearance_penalty on an env that is not a MARA arm."""
    params = getattr(env, "default_params", None)
    layout = getattr(env, "observation_layout", None) or []
    resolved = curriculum
    if not hasattr(params, "reward"):
        resolved = resolved.replace(train_reward="", train_collision_penalty=0.0)
    if not hasattr(params, "reset_noise"):
        resolved = resolved.replace(train_reset_noise=0.0, train_reset_noise_final=-1.0)
    has_quat = any(part.get("name") == "quat_err" for part in layout)
    if not has_quat and resolved.orientation_bonus > 0.0:  # no orientation in the task
        resolved = resolved.replace(orientation_bonus=0.0)
    where = {part.get("name"): int(part["start"]) for part in layout}
    arm = where.get("q") == 0 and getattr(env, "action_size", None) == 6
    if resolved.train_clearance_penalty > 0.0 and not arm:
        raise ValueError(
            f"train_clearance_penalty={resolved.train_clearance_penalty} reads the MARA "
            "arm's joints (q at 0 of the observation, 6 joint actions); this env has "
            "neither; set train_clearance_penalty=0"
        )
    return resolved


def limit_penalty(q: jax.Array, lower: jax.Array, upper: jax.Array, soft: float) -> jax.Array:
    """sum_j relu(|q_j - c_j| - soft h_j) / ((1 - soft) h_j): 0 inside the soft range, 1 per
    joint at its limit (CurriculumConfig.train_limit_penalty); q (..., J)."""
    centre, half = (upper + lower) / 2, (upper - lower) / 2
    return jnp.sum(jax.nn.relu(jnp.abs(q - centre) - soft * half) / ((1 - soft) * half), -1)


def clearance_penalty(
    q: jax.Array, q_next: jax.Array, margin: float, points: int, path: str
) -> jax.Array:
    """relu(1 - c / margin): 0 beyond `margin` (m) from every contact of the nominal arm, 1
    at contact (CurriculumConfig.train_clearance_penalty); q, q_next (..., 6). c is the
    smallest clearance at `points` evenly spaced postures of the way from q to q_next
    (q_next included, q not): 'servo', q + clip(dq, -s, s) for s up to max |dq| (each
    joint at one speed until it arrives), or 'line', q + t dq."""
    from mara_mjx.envs.clearance import clearance

    dq = (q_next - q)[..., None, :]
    t = (jnp.arange(1, points + 1, dtype=q.dtype) / points)[:, None]  # (points, 1)
    if path == "servo":
        s = t * jnp.max(jnp.abs(dq), -1, keepdims=True)
        way = jnp.clip(dq, -s, s)
    else:
        way = t * dq
    c = jnp.min(clearance(q[..., None, :] + way), -1)
    return jax.nn.relu(1.0 - c / margin)


def capped_envs(config: CurriculumConfig, num_envs: int) -> Callable | None:
    """(env_action, q, probe) -> env_action with the last `train_capped_fraction` of the
    `num_envs` moving each joint at most `train_capped_step` from the observed q (not on
    the probe step), or None when off (CurriculumConfig.train_capped_fraction)."""
    if config.train_capped_fraction <= 0.0:
        return None
    n = round(config.train_capped_fraction * num_envs)
    mask = (jnp.arange(num_envs) >= num_envs - n)[:, None]
    step = config.train_capped_step

    def cap(action: jax.Array, q: jax.Array, probe: jax.Array) -> jax.Array:
        return jnp.where(mask & ~probe, jnp.clip(action, q - step, q + step), action)

    return cap


def orientation_bonus(metrics: dict[str, jax.Array], config: CurriculumConfig) -> jax.Array:
    """w exp(-d / d0) exp(-theta / theta0) on non-colliding steps
    (CurriculumConfig.orientation_bonus)."""
    bonus = config.orientation_bonus * jnp.exp(
        -metrics["distance"] / config.orientation_bonus_distance
        - metrics["angle"] / config.orientation_bonus_angle
    )
    if "collided" in metrics:
        bonus = jnp.where(metrics["collided"] > 0, 0.0, bonus)
    return bonus


class Schedule(NamedTuple):
    """The curriculum as functions of the trainer's state (`make_schedule`)."""

    frac: Callable[[jax.Array], jax.Array]
    """update -> how far the curricula are toward their ends: 0 at the first update, 1
    from train_reward_until of the updates on."""
    rollout_state: Callable[[Any, jax.Array], Any]
    """(BatchedState, update) -> the state with the rollout's reward hyperparameters and
    reset noise (train_reward, train_reset_noise at `frac` of the way to their ends)."""
    initial_params: Callable[[], Any]
    """() -> the env params of the first episodes (None: the env's defaults)."""
    stagger: Callable[[Any, jax.Array], tuple[Any, jax.Array]]
    """(BatchedState, key) -> (state, key): stagger_episodes' random first steps."""
    shaped_reward: Callable[[jax.Array, Any, Any, jax.Array], jax.Array]
    """(reward, rollout Transition, BatchedState after it, update) -> the reward PPO
    learns from: the env's, with the training-only penalties and bonus."""


def make_schedule(config: CurriculumConfig, env: Any, benv: Any, num_updates: int) -> Schedule:
    """The Schedule of `config` for `benv` (a BatchedEnv of `env`) over `num_updates`."""
    curriculum = reward_curriculum(config.train_reward)
    for name, value in curriculum.items():  # its start; the way to the env's own stays in
        try:  # range (the ranges are intervals)
            check_reward_value(name, value)
        except ValueError as e:
            raise ValueError(f"train_reward: {e}") from None
    until = max(1.0, config.train_reward_until * num_updates)
    lower = jnp.asarray(getattr(env, "joint_lower", -jnp.inf), jnp.float32)
    upper = jnp.asarray(getattr(env, "joint_upper", jnp.inf), jnp.float32)

    def frac(update: jax.Array) -> jax.Array:
        return jnp.clip(update.astype(jnp.float32) / until, 0.0, 1.0)

    def curriculum_params(params: Any, at: jax.Array) -> Any:
        """`params` with `train_reward` and `train_reset_noise` `at` (0 to 1) of the way
        from the config's values to their ends (the env's own unless final is set)."""
        own = benv.env.default_params
        if curriculum:
            reward = params.reward.replace(
                **{
                    k: jnp.full_like(
                        getattr(params.reward, k), v + at * (getattr(own.reward, k) - v)
                    )
                    for k, v in curriculum.items()
                }
            )
            params = params.replace(reward=reward)
        if config.train_reset_noise > 0.0:
            v, end = config.train_reset_noise, config.train_reset_noise_final
            end = own.reset_noise if end < 0.0 else end
            noise = jnp.full_like(params.reset_noise, v + at * (end - v))
            params = params.replace(reset_noise=noise)
        return params

    def rollout_state(env_state: Any, update: jax.Array) -> Any:
        if not curriculum and config.train_reset_noise <= 0.0:
            return env_state
        params = curriculum_params(env_state.env_state.params, frac(update))
        return env_state.replace(env_state=env_state.env_state.replace(params=params))

    def initial_params() -> Any:
        if config.train_reset_noise <= 0.0:
            return None
        own = benv.env.default_params
        return own.replace(reset_noise=curriculum_params(own, 0.0).reset_noise)

    def stagger(env_state: Any, key: jax.Array) -> tuple[Any, jax.Array]:
        if not (config.stagger_episodes and hasattr(env_state.env_state, "step")):
            return env_state, key
        key, stagger_key = jax.random.split(key)
        horizon = benv.env.max_episode_steps
        steps = jax.random.randint(stagger_key, (benv.num_envs,), 0, horizon, jnp.int32)
        inner = env_state.env_state.replace(step=steps)
        return sharding.constrain(env_state.replace(env_state=inner), benv.mesh), key

    def shaped_reward(reward: jax.Array, traj: Any, env_state: Any, update: jax.Array):
        fade = 1.0 - frac(update)  # the training-only penalties' weight
        if config.train_collision_penalty > 0.0 and "collided" in traj.metrics:
            own = env_state.env_state.params.reward  # (N,) leaves
            penalty = collision_penalty(
                traj.metrics["distance"], traj.metrics["collided"], own.delta, own.eta
            )
            reward = reward - fade * config.train_collision_penalty * penalty
        if config.orientation_bonus > 0.0:
            reward = reward + orientation_bonus(traj.metrics, config)
        if config.train_limit_penalty > 0.0 and hasattr(env, "joint_lower"):
            q = traj.obs[..., : lower.shape[-1]]
            reward = reward - fade * config.train_limit_penalty * limit_penalty(
                q, lower, upper, config.train_limit_soft
            )
        if config.train_clearance_penalty > 0.0:
            q = traj.obs[..., : lower.shape[-1]]
            q_next = traj.final_obs[..., : lower.shape[-1]]  # the landing, before any reset
            reward = reward - config.train_clearance_penalty * clearance_penalty(
                q,
                q_next,
                config.train_clearance_mm * 1e-3,
                config.train_clearance_points,
                config.train_clearance_path,
            )
        return reward

    return Schedule(frac, rollout_state, initial_params, stagger, shaped_reward)
