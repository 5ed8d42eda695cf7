"""The four MARA tasks with a new target pose every episode.

    task                              parent (reward, observation, drivers, episode rules)
    MARARandomTarget                  MARA                 q, e, v (12)
    MARAOrientRandomTarget            MARAOrient           q, e, quat_err, v (16)
    MARACollisionRandomTarget         MARACollision        q, e, v (12)
    MARACollisionOrientRandomTarget   MARACollisionOrient  q, e, quat_err, v (16)

Everything is the parent's (mara.py: the observation table, the action, the rewards with
the parent's beta, both drivers, collisions, truncation) except where the target comes
from:

* `reset` draws one pose of the pose table held in the params (`table_pos` (K, 3) m,
  `table_quat` (K, 4)), uniformly by index: one `randint` and a gather, so the reset stays
  cheap although `BatchedEnv` computes a reset for every env at every step. The episode's
  target goes into `state.params.target_pos` / `target_quat`, so e and quat_err are
  relative to it, and into the metrics `target_pos` (3,) m and `target_quat` (4,)
  (w, x, y, z), present from reset on.
* The table (K = `target_table_size`, 1024 by default) is made on the host when the
  params are made (`envs/targets.py`: forward kinematics of collision-free joint
  configurations inside the joint limits, filtered to the region, balanced over the
  box; about 0.5 s for the default Orient region on one CPU core, once per process and
  region). Every drawn pose is reachable exactly and without collision.
* The region: the TCP position in the box [target_min, target_max] (m, world frame) and,
  for the Orient tasks, the flange orientation within target_spread_deg (30 by default)
  of target_quat (the spec's tool-pointing-down pose). The position-only tasks default to
  target_spread_deg = 180 (any orientation: they do not observe it). `target_pos` is not
  used (the table's first pose stands in for it before the first reset).

Changing the region: `make(name, target_min=..., target_max=..., target_spread_deg=...)`
builds an env with it; `env.make_params(target_min=..., ...)` returns params with a new
table of the same shape, so the compiled reset and step serve it without recompiling
(a new `target_table_size` changes the shape, and recompiles). An empty region is a
ValueError naming the fields.

A table of one pose fixes the target: `target_eval` evaluates held-out poses that way.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from mara_mjx.envs import targets
from mara_mjx.envs.base import METRIC_KEYS, EnvConfig, EnvParams, EnvState
from mara_mjx.envs.mara import TASKS, MaraEnv, Task, default_config

SUFFIX = "RandomTarget"
TARGET_METRIC_KEYS = (
    "target_pos",  # (3,) m, world frame, this episode's target TCP position
    "target_quat",  # (4,) (w, x, y, z), this episode's target orientation
)
POSITION_ONLY_SPREAD_DEG = 180.0

RANDOM_TASKS = {
    f"{t.name}{SUFFIX}": dataclasses.replace(t, name=f"{t.name}{SUFFIX}") for t in TASKS.values()
}
PARENTS = {f"{name}{SUFFIX}": name for name in TASKS}

# (region, size, seed) -> PoseTable: the arm model is one per process (mara._shared_arm).
_TABLES: dict[tuple, targets.PoseTable] = {}


@struct.dataclass
class RandomTargetParams(EnvParams):
    """EnvParams plus the pose table the episode targets are drawn from."""

    table_pos: jax.Array  # (K, 3) m, world frame
    table_quat: jax.Array  # (K, 4) (w, x, y, z), unit


def random_target_config(task: Task) -> EnvConfig:
    """The parent task's defaults; the position-only tasks allow any orientation."""
    cfg = default_config(task)
    return cfg if task.orientation else cfg.replace(target_spread_deg=POSITION_ONLY_SPREAD_DEG)


class RandomTargetEnv(MaraEnv):
    """A MARA task whose target pose is drawn from a pose table at every reset."""

    metric_keys = METRIC_KEYS + TARGET_METRIC_KEYS

    def __init__(self, task: Task, config: EnvConfig | None = None):
        super().__init__(task, config if config is not None else random_target_config(task))

    def __repr__(self) -> str:
        return f"RandomTargetEnv({self.task.name}, driver={self.config.driver!r})"

    @property
    def region(self) -> targets.TargetRegion:
        return targets.TargetRegion.from_config(self.config)

    def pose_table(self, config: EnvConfig | None = None) -> targets.PoseTable:
        """The training pose table (host side, float64, with its joint configurations) of
        `config` (default: this env's)."""
        cfg = self.config if config is None else config
        region = targets.TargetRegion.from_config(cfg)
        key = (region, cfg.target_table_size, cfg.target_seed)
        if key not in _TABLES:
            _TABLES[key] = targets.training_table(
                self.arm.mj_model, region, cfg.target_table_size, cfg.target_seed
            )
        return _TABLES[key]

    def make_params(self, **overrides) -> RandomTargetParams:
        """Params with the pose table of this env's region, or of the region given in
        `overrides` (target_min, target_max, target_quat, target_spread_deg, target_seed:
        same shapes, no recompile), plus the overrides of `MaraEnv.make_params`."""
        cfg = self.config.replace(**overrides) if overrides else self.config
        base = super().make_params(**overrides)
        table = self.pose_table(cfg)
        f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
        fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(EnvParams)}
        fields.update(target_pos=f32(table.pos[0]), target_quat=f32(table.quat[0]))
        return RandomTargetParams(**fields, table_pos=f32(table.pos), table_quat=f32(table.quat))

    def _check_target(self, cfg: EnvConfig) -> None:
        """Nothing to check: every table pose is reachable by construction (target_pos is
        not used)."""

    def reset(self, key: jax.Array, params: RandomTargetParams | None = None) -> EnvState:
        """The parent's reset with a target drawn uniformly from the params' table."""
        params = self.default_params if params is None else params
        key, target_key = jax.random.split(key)
        i = jax.random.randint(target_key, (), 0, params.table_pos.shape[0])
        params = params.replace(target_pos=params.table_pos[i], target_quat=params.table_quat[i])
        return super().reset(key, params)

    def _observe(self, q, pose, qvel, params):
        obs, metrics, theta = super()._observe(q, pose, qvel, params)
        metrics.update(target_pos=params.target_pos, target_quat=params.target_quat)
        return obs, metrics, theta


def with_targets(params: RandomTargetParams, pos, quat) -> RandomTargetParams:
    """Params whose table holds one pose per row of pos (E, 3) / quat (E, 4), with a
    leading (E,) axis on every leaf: `jax.vmap(env.reset)(keys, params)` then starts
    episode i at target i."""
    pos, quat = jnp.asarray(pos, jnp.float32), jnp.asarray(quat, jnp.float32)
    n = pos.shape[0]
    # Drop the training table before broadcasting: E copies of it are not needed.
    one = params.replace(table_pos=pos[:1], table_quat=quat[:1])
    batched = jax.tree.map(lambda x: jnp.broadcast_to(x, (n, *jnp.shape(x))), one)
    return batched.replace(
        target_pos=pos, target_quat=quat, table_pos=pos[:, None], table_quat=quat[:, None]
    )


def is_random_target(env) -> bool:
    return isinstance(env, RandomTargetEnv)


__all__ = [
    "PARENTS",
    "RANDOM_TASKS",
    "RandomTargetEnv",
    "RandomTargetParams",
    "is_random_target",
    "random_target_config",
    "with_targets",
]
