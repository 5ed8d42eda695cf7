"""PPO configuration: frozen dataclasses, one docstring per field (the presets: `ppo.presets`).

    PPOConfig      the algorithm and its networks' shape (what a PureJaxRL or brax reader
                   expects: batch, epochs, GAE, clipping, Adam, the MLP, normalisation)
    TrainConfig    what `make_train` compiles: TrainConfig(ppo, policy, curriculum), the
                   PPOConfig, the policy's parametrisation (`parametrisation.PolicyConfig`:
                   joint deltas, the IK residual and its rules) and the training-only
                   shaping (`curriculum.CurriculumConfig`: reward schedules, penalties,
                   staggering, population); `.replace(ik_finish=0.06, num_envs=8)` routes
                   each field to its section, `TrainConfig.of(**fields)` builds one so
    for_env(config, env) -> the TrainConfig with its env-dependent fields resolved
    (the named TrainConfigs, PRESETS, and the train CLI's pick per task: `ppo.presets`)
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
