"""PPO configuration: frozen dataclasses, one docstring per field, presets as instances.

    PPOConfig      the algorithm and its networks' shape (what a PureJaxRL or brax reader
                   expects: batch, epochs, GAE, clipping, Adam, the MLP, normalisation)
    TrainConfig    what `make_train` compiles: TrainConfig(ppo, policy, curriculum), the
                   PPOConfig, the policy's parametrisation (`parametrisation.PolicyConfig`:
                   joint deltas, the IK residual and its rules) and the training-only
                   shaping (`curriculum.CurriculumConfig`: reward schedules, penalties,
                   staggering, population); `.replace(ik_finish=0.06, num_envs=8)` routes
                   each field to its section, `TrainConfig.of(**fields)` builds one so
    PRESETS        {"default", "ik_finish", "paper", "ros2learn", "random_target",
                    "staggered", "staggered_ik_finish", "random_target_orient",
                    "random_target_orient_plan", "random_target_plan",
                    "random_target_plan_guard", "orient_first", "cpu", "distill"} -> TrainConfig
    default_preset(env_name) -> the train CLI's preset when none is given
    for_env(config, env) -> the TrainConfig with its env-dependent fields resolved
    RunConfig, EvalConfig (`mara_mjx.ppo.run_config`): the host loop, the evaluation

Run folders and checkpoints keep the three sections as "ppo", "policy" and "curriculum";
one written before the split kept them all, flat, under "ppo": `upgrade_meta` converts it
(a field since removed is dropped at its default, and named in an error otherwise).
The CLIs (`python -m mara_mjx.train`, `python -m mara_mjx.evaluate`) generate one flag per
field from these classes (`mara_mjx.cli.common`; the three sections' flags are all
`--field` and `--ppo.field`, as before the split), with the field docstrings as help text;
the shared config machinery (to_dict/from_dict/replace, validators) is `mara_mjx.config`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

from mara_mjx.config import ConfigMixin as _ConfigMixin
from mara_mjx.config import check_int as _check_int
from mara_mjx.config import check_range as _check_range
from mara_mjx.config import is_int as _is_int
from mara_mjx.ppo import curriculum as _curriculum
from mara_mjx.ppo import parametrisation as _parametrisation
from mara_mjx.ppo.curriculum import CurriculumConfig
from mara_mjx.ppo.parametrisation import PolicyConfig
from mara_mjx.ppo.run_config import EvalConfig as EvalConfig  # re-exported
from mara_mjx.ppo.run_config import RunConfig as RunConfig  # re-exported

LR_SCHEDULES = ("linear", "exp", "constant")
# The optimiser's step counter is an int32 inside the jitted update.
_MAX_OPTIMIZER_STEPS = 2**31 - 1


@dataclasses.dataclass(frozen=True)
class PPOConfig(_ConfigMixin):
    """PPO as in OpenAI baselines ppo2 (the paper's implementation), batched over envs.

    Defaults are the paper's hyperparameters (spec section 7); see `PRESETS`.
    One update collects `num_envs * num_steps` transitions, then runs `update_epochs`
    passes of `num_minibatches` Adam steps over them. Fields no preset changes
    (clip_value, normalize_advantages, adam_eps, obs_clip, ent_coef, gae_lambda) stay:
    they are baselines ppo2's switches, which a comparison with it or brax names.
    """

    num_envs: int = 1
    """Environments stepped in parallel (one BatchedEnv)."""
    num_steps: int = 2048
    """Steps per environment per rollout; a batch is num_envs * num_steps transitions."""
    total_timesteps: int = 100_000_000
    """Training budget in env steps; updates = total_timesteps // (num_envs * num_steps)."""
    num_minibatches: int = 32
    """Minibatches per epoch; must divide num_envs * num_steps. Minibatches are stratified
    by env (each holds num_steps / num_minibatches random steps of every env when that
    divides; ppo.optim.stratified_minibatches)."""
    update_epochs: int = 10
    """Passes over each batch (reshuffled every pass)."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    clip_eps: float = 0.2
    """PPO clip range of the probability ratio (also of the value change if clip_value)."""
    clip_value: bool = True
    """Clipped value loss (baselines ppo2): max of the plain and the clipped squared error."""
    vf_coef: float = 0.5
    """Value loss coefficient."""
    ent_coef: float = 0.0
    """Entropy bonus coefficient."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip."""
    adam_eps: float = 1e-5
    """Adam epsilon (baselines ppo2 uses 1e-5)."""
    learning_rate: float = 3e-4
    """Initial Adam learning rate."""
    lr_schedule: Literal["linear", "exp", "constant"] = "linear"
    """'linear': lr * (1 - update / updates), to 0 at the end (baselines). 'exp':
    max(lr * exp(-lr_decay_rate * update), lr_floor) (ROS2Learn). 'constant': lr. The rate
    is constant within one update."""
    lr_decay_rate: float = 0.001918
    """Per-update decay rate of the 'exp' schedule."""
    lr_floor: float = 1e-4
    """Lower bound of the 'exp' schedule."""
    hidden_sizes: tuple[int, ...] = (64, 64)
    """Hidden layer widths of the policy MLP and of the separate value MLP (tanh)."""
    init_log_std: float = 0.0
    """Initial value of the state-independent log standard deviation (rad)."""
    log_std_floor: float = -20.0
    """Lower bound of the log standard deviation (the parameter is clamped with max(., floor)
    wherever it is used); -20 is no bound."""
    normalize_obs: bool = False
    """Normalise observations by running mean and variance of the rollouts (Welford); the
    statistics are saved with the policy and applied by make_policy."""
    obs_clip: float = 10.0
    """With normalize_obs: clip normalised observations to [-obs_clip, obs_clip]."""
    normalize_advantages: bool = True
    """Normalise advantages per minibatch (baselines ppo2)."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this before GAE, so values learn scaled returns (logged
    rewards stay unscaled). The MARA rewards reach 10 per step, so with gamma 0.99 returns
    reach 1000, far outside what the clipped value loss (clip_eps per update) can follow."""
    seed: int = 0
    """PRNG seed of initialisation, environments, action noise and shuffling."""

    def __post_init__(self):
        for name in ("num_envs", "num_steps", "total_timesteps", "num_minibatches"):
            _check_int(name, getattr(self, name), minimum=1)
        _check_int("update_epochs", self.update_epochs, minimum=1)
        _check_int("seed", self.seed, minimum=0)
        if self.num_minibatches > self.batch_size or self.batch_size % self.num_minibatches:
            divisors = [
                d for d in range(1, min(self.batch_size, 4096) + 1) if not self.batch_size % d
            ]
            raise ValueError(
                f"num_minibatches={self.num_minibatches} does not divide the batch of "
                f"num_envs * num_steps = {self.num_envs} * {self.num_steps} = {self.batch_size} "
                f"transitions; choose num_minibatches among {divisors[:24]}"
                + (" ..." if len(divisors) > 24 else "")
            )
        if self.total_timesteps < self.batch_size:
            raise ValueError(
                f"total_timesteps={self.total_timesteps} is less than one update of "
                f"num_envs * num_steps = {self.batch_size} env steps"
            )
        steps = self.num_updates * self.update_epochs * self.num_minibatches
        if steps > _MAX_OPTIMIZER_STEPS:
            raise ValueError(
                f"{self.num_updates} updates x {self.update_epochs} epochs x "
                f"{self.num_minibatches} minibatches = {steps} optimiser steps overflows the "
                "int32 step counter; use fewer updates or larger batches"
            )
        _check_range("gamma", self.gamma, 0.0, 1.0, low_open=True)
        _check_range("gae_lambda", self.gae_lambda, 0.0, 1.0)
        for name in ("clip_eps", "max_grad_norm", "adam_eps", "learning_rate", "obs_clip"):
            _check_range(name, getattr(self, name), 0.0, math.inf, low_open=True)
        _check_range("reward_scale", self.reward_scale, 0.0, math.inf, low_open=True)
        for name in ("vf_coef", "ent_coef", "lr_decay_rate", "lr_floor"):
            _check_range(name, getattr(self, name), 0.0, math.inf)
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(
                f"lr_schedule={self.lr_schedule!r} is not valid; choose one of {LR_SCHEDULES}"
            )
        if (
            not isinstance(self.hidden_sizes, tuple)
            or not self.hidden_sizes
            or not all(_is_int(h) and h >= 1 for h in self.hidden_sizes)
        ):
            raise ValueError(
                f"hidden_sizes={self.hidden_sizes!r} must be a non-empty tuple of positive ints"
            )
        _check_range("init_log_std", self.init_log_std, -20.0, 5.0)
        _check_range("log_std_floor", self.log_std_floor, -20.0, 5.0)
        if self.log_std_floor > self.init_log_std:
            raise ValueError(
                f"log_std_floor={self.log_std_floor} is above init_log_std={self.init_log_std}"
            )
        for name in ("clip_value", "normalize_obs", "normalize_advantages"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")

    @property
    def batch_size(self) -> int:
        """Transitions per update: num_envs * num_steps."""
        return self.num_envs * self.num_steps

    @property
    def minibatch_size(self) -> int:
        return self.batch_size // self.num_minibatches

    @property
    def num_updates(self) -> int:
        """PPO updates in the run: total_timesteps // batch_size (as baselines)."""
        return self.total_timesteps // self.batch_size


SECTIONS = {"ppo": PPOConfig, "policy": PolicyConfig, "curriculum": CurriculumConfig}
"""TrainConfig's sections: their names in TrainConfig, config.json and checkpoints."""
OWNER = {f.name: section for section, cls in SECTIONS.items() for f in dataclasses.fields(cls)}
"""{field name: the section that holds it} (the names are unique across the sections)."""
REMOVED: dict[str, Any] = {}
"""{field: its last default} of fields removed since checkpoints were first written: a
pre-split config that holds one at that value loads without it; any other value is an
error naming the field (its run trained with something this version cannot do)."""


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything `make_train` compiles, in three sections of separate responsibility."""

    ppo: PPOConfig = PPOConfig()
    """The algorithm (PPOConfig)."""
    policy: PolicyConfig = PolicyConfig()
    """The policy's parametrisation (parametrisation.PolicyConfig), the saved policy's too."""
    curriculum: CurriculumConfig = CurriculumConfig()
    """Training-only shaping (curriculum.CurriculumConfig)."""

    def __post_init__(self):
        for name, cls in SECTIONS.items():
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"TrainConfig.{name} must be a {cls.__name__}")

    @classmethod
    def of(cls, **fields: Any) -> TrainConfig:
        """TrainConfig().replace(**fields): the defaults with the fields, any section's."""
        return cls().replace(**fields)

    def replace(self, **overrides: Any) -> TrainConfig:
        """A new config: each override is a section (ppo=PPOConfig(...)) or a field of one
        (num_envs=8, ik_finish=0.06), validated by its section; unknown names raise."""
        unknown = sorted(k for k in overrides if k not in OWNER and k not in SECTIONS)
        if unknown:
            raise ValueError(
                f"unknown PPOConfig, PolicyConfig or CurriculumConfig field(s) {unknown}; "
                f"valid fields are {sorted(OWNER)}"
            )
        sections = {k: v for k, v in overrides.items() if k in SECTIONS}
        for name in SECTIONS:
            fields = {k: v for k, v in overrides.items() if OWNER.get(k) == name}
            if fields:
                sections[name] = sections.get(name, getattr(self, name)).replace(**fields)
        return dataclasses.replace(self, **sections)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """{"ppo": {...}, "policy": {...}, "curriculum": {...}} (JSON-ready)."""
        return {name: getattr(self, name).to_dict() for name in SECTIONS}

    def flat(self) -> dict[str, Any]:
        """Every field of the three sections in one dict (the pre-split PPOConfig's)."""
        return {k: v for name in SECTIONS for k, v in getattr(self, name).to_dict().items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        """From `to_dict()` output, or from a pre-split flat PPOConfig dict
        (`upgrade_meta`); ValueError naming unknown or removed fields."""
        if not set(data) <= set(SECTIONS):  # a flat dict of fields
            data = split_flat(data)
        return cls(**{k: SECTIONS[k].from_dict(v) for k, v in data.items()})

    @classmethod
    def from_meta(cls, meta: dict[str, Any]) -> TrainConfig:
        """The TrainConfig of a checkpoint's meta or a run's config.json, either layout."""
        return cls.from_dict({k: v for k, v in upgrade_meta(meta).items() if k in SECTIONS})


def as_train_config(config: PPOConfig | TrainConfig) -> TrainConfig:
    """A PPOConfig alone is TrainConfig(ppo=config) (the default policy, no curriculum)."""
    return TrainConfig(ppo=config) if isinstance(config, PPOConfig) else config


def split_flat(flat: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """A pre-split flat PPOConfig dict as {"ppo": ..., "policy": ..., "curriculum": ...}:
    each field under its section, a removed field (REMOVED) dropped at its default and an
    error otherwise; unknown names stay under "ppo" (PPOConfig.from_dict names them)."""
    out: dict[str, dict[str, Any]] = {name: {} for name in SECTIONS}
    for key, value in flat.items():
        if key in REMOVED:
            if value != REMOVED[key]:
                raise ValueError(
                    f"the config sets {key}={value!r}, a field this version no longer has "
                    f"(its only value now is {REMOVED[key]!r}); train with the version that "
                    "wrote it, or set it to that value in the config to load it here"
                )
            continue
        out[OWNER.get(key, "ppo")][key] = value
    return out


def upgrade_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's meta or a run's config.json in the present layout: one written
    before the PPOConfig split (every field flat under "ppo", no "policy") gets its
    "ppo" split into "ppo", "policy" and "curriculum"; any other is returned as is."""
    if not isinstance(meta.get("ppo"), dict) or "policy" in meta:
        return meta
    return {**meta, **split_flat(meta["ppo"])}


def for_env(config: PPOConfig | TrainConfig, env: Any) -> TrainConfig:
    """`config` with the env-dependent fields resolved: the policy's
    (`parametrisation.resolve`: quat_index from the env's observation layout, the
    orientation rules cleared for a task without one) and the curriculum's
    (`curriculum.resolve`: what the env's params cannot apply cleared)."""
    config = as_train_config(config)
    return config.replace(
        policy=_parametrisation.resolve(config.policy, env),
        curriculum=_curriculum.resolve(config.curriculum, env),
    )


PRESETS: dict[str, TrainConfig] = {
    # For thousands of environments on one GPU (benchmarks/NOTES.md, sections 4 and 6).
    # 2048 x 32 and reward_scale 0.01 were the fastest to 1 mm of the shapes and scales
    # measured on an H200 (benchmarks/results/ppo_sweep.md). relative_actions, the log-std
    # floor (sigma >= 0.01 rad) and gamma 0.9 are what made the learned policy stay at the
    # target instead of cycling around it (benchmarks/results/ppo_variants/).
    "default": TrainConfig.of(
        num_envs=2048,
        num_steps=32,
        total_timesteps=50_000_000,
        num_minibatches=32,
        update_epochs=4,
        gamma=0.9,
        normalize_obs=True,
        reward_scale=0.01,
        relative_actions=True,
        log_std_floor=-4.6,
        # The orientation fixes (benchmarks/NOTES.md, section 12): during the first half
        # of training collisions are penalised (so that no seed commits to a colliding,
        # joint-limit-saturated posture) and orientation weighs more (beta 0.5, gamma
        # 0.02), both fading to the env's own reward; the mean kept inside the joint box;
        # the quaternion error read with a canonical sign; a narrower initial noise.
        init_log_std=-1.0,
        canonical_quat=True,
        bound_coef=1.0,
        train_collision_penalty=1.0,
        train_reward="beta=0.5,gamma=0.02",
        train_reward_until=0.5,
    ),
    # The paper's appendix: baselines ppo2, one environment (spec section 7).
    "paper": TrainConfig(),
    # The later ROS2Learn configuration of the same group.
    "ros2learn": TrainConfig.of(
        num_steps=1024,
        num_minibatches=4,
        hidden_sizes=(16, 16),
        learning_rate=3e-3,
        lr_schedule="exp",
        lr_decay_rate=0.001918,
        lr_floor=1e-4,
        clip_eps=0.25,
        vf_coef=1.0,
    ),
}

# The default with staggered first episodes (issue 12): with a new target every episode,
# synchronised episodes left too few updates that see the reach and training collapsed on
# some seeds (benchmarks/NOTES.md section 19). The learnt step alone on random targets.
PRESETS["random_target"] = PRESETS["default"].replace(stagger_episodes=True)
# The same on MARACollision (benchmarks/NOTES.md section 27: position worst 2.17 mm per
# axis against the default's 4.64). Not on MARA: one seed of five held its pose colliding.
PRESETS["staggered"] = PRESETS["random_target"]
# Imitation of a teacher run instead of reward (--teacher RUN, required; NOTES section 51):
# a plain network 4x as wide (256 x 256), staggering, no IK deployed (mara_mjx.ppo.teacher).
PRESETS["distill"] = PRESETS["random_target"].replace(hidden_sizes=(256, 256))

# MARA, the train CLI's choice there (benchmarks/NOTES.md sections 27-28 and 52): the
# default's training, its last 6 cm the IK step's (ik_finish), in both export formats.
PRESETS["ik_finish"] = PRESETS["default"].replace(ik_finish=0.06)
# MARACollision, the train CLI's choice there: `staggered` with the same finish.
PRESETS["staggered_ik_finish"] = PRESETS["staggered"].replace(ik_finish=0.06)

# The random-target tasks with an orientation (issue 12, benchmarks/NOTES.md sections
# 23-24): random_target, a soft joint-limit penalty during training, and an actor that
# learns a correction to a damped-least-squares IK step toward the observed pose (ik_prior
# residual), faded out within ~10 cm of the target and while the step turns the flange the
# long way round (ik_gate, ik_wrap, ik_gate_wrap). .onnx export only (the arm's Jacobian).
PRESETS["random_target_orient"] = PRESETS["random_target"].replace(
    total_timesteps=120_000_000,
    train_limit_penalty=1.0,
    train_reward_until=1.0,
    ik_prior="residual",
    ik_gate=0.1,
    ik_wrap=True,
    ik_gate_wrap=True,
)

# The *OrientRandomTarget tasks, the train CLI's choice there (benchmarks/NOTES.md
# sections 47-49 and 54): the same training, deploying the plan (plan_steps) and its
# restarts from 16 other postures where the own landing misses (plan_starts).
PRESETS["random_target_orient_plan"] = PRESETS["random_target_orient"].replace(
    plan_steps=16,
    plan_starts=16,
)

# MARARandomTarget, the train CLI's choice there (benchmarks/NOTES.md section 53): the same
# at the default's 5e7 env steps; 16 fresh seeds >= 99.9% within 1 mm (random_target: 9 fail).
PRESETS["random_target_plan"] = PRESETS["random_target_orient_plan"].replace(
    total_timesteps=PRESETS["default"].ppo.total_timesteps,
)
# MARACollisionRandomTarget, the train CLI's choice there: with orient_first's deployed
# 5-mm collision guard (section 53: no episode colliding, 1.5% without it).
PRESETS["random_target_plan_guard"] = PRESETS["random_target_plan"].replace(
    collision_guard_mm=5.0,
)

# The fixed-target Orient tasks (issue 11, benchmarks/NOTES.md sections 26-27 and 38),
# the train CLI's choice for MARAOrient and MARACollisionOrient: the IK-residual part of
# random_target_orient at the default's 5e7 steps, the IK step turning the tool before
# the TCP closes in (ik_orient_first), staggered episodes (synchronised ones let the
# converged policies drift), two training-only rules (the roll gate, the standoff's loose
# form), a probe of the saved policy from the reset after every jitted call (the one-step
# det_error_mm cannot show the orient-first rule), a deployed 5-mm collision guard and the
# deployed plan with its restarts (section 60: fresh seeds held wrong fixed points).
PRESETS["orient_first"] = PRESETS["random_target_orient"].replace(
    total_timesteps=PRESETS["default"].ppo.total_timesteps,
    ik_orient_first=True,
    train_ik_gate_roll=True,
    probe_reach_steps=100,
    collision_guard_mm=5.0,
    plan_steps=16,
    plan_starts=16,
)


def default_preset(env_name: str) -> str:
    """The preset the train CLI uses for `env_name` when none is given: per task, the one
    measured best on it (benchmarks/NOTES.md sections 19, 24, 27, 48, 53 and 54)."""
    if env_name.endswith("OrientRandomTarget"):
        return "random_target_orient_plan"
    if env_name == "MARACollisionRandomTarget":
        return "random_target_plan_guard"
    if env_name.endswith("RandomTarget"):
        return "random_target_plan"
    return {
        "MARAOrient": "orient_first",
        "MARACollisionOrient": "orient_first",
        "MARACollision": "staggered_ik_finish",
        "MARA": "ik_finish",
    }.get(env_name, "default")


# A laptop CPU (2 cores): 256 envs x 16 steps, a higher learning rate and a narrower initial
# policy: ~50x fewer env steps to 5 mm than the default (benchmarks/results/cpu/).
PRESETS["cpu"] = PRESETS["default"].replace(
    num_envs=256,
    num_steps=16,
    num_minibatches=4,
    learning_rate=1e-3,
    init_log_std=-1.0,
    total_timesteps=3_000_000,
    # as measured: without the GPU default's orientation fixes
    canonical_quat=False,
    bound_coef=0.0,
    train_collision_penalty=0.0,
    train_reward="",
)
