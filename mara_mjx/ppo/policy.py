"""The policy artefact and its one factory, `make_policy`.

A policy is params + config (+ observation statistics when the run normalised them). The
deterministic policy is the Gaussian mean: absolute joint targets (rad) for the env,
which clips them to the joint limits.

    policy = make_policy("runs/MARA-.../checkpoints/ckpt_00000100.npz")   # or load_policy
    action = policy(obs)                       # (obs_size,) or (N, obs_size) -> (..., 6)
    action = jax.jit(policy)(obs)              # or pass `policy` into a jitted function:
                                               # it is a pytree (params traced, config static)
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mara_mjx.ppo.checkpoint import (
    CheckpointError,
    arrays_to_state,
    find_checkpoint,
    load_checkpoint,
)
from mara_mjx.ppo.config import PPOConfig, TrainConfig, as_train_config
from mara_mjx.ppo.members import member_axis
from mara_mjx.ppo.networks import ActorCritic, RunningStats, forward, make_network


@struct.dataclass
class Policy:
    """Deterministic policy obs -> Gaussian mean. A pytree: pass it through jit/vmap."""

    params: Any
    obs_stats: RunningStats | None
    config: TrainConfig = struct.field(pytree_node=False)
    action_size: int = struct.field(pytree_node=False)

    @property
    def network(self) -> ActorCritic:
        return make_network(self.config, self.action_size)

    def one_step(self) -> Policy:
        """This policy without its deployed plan and restarts (PolicyConfig.plan_steps,
        plan_starts): its own next step, what the plan imagines and a teacher labels with."""
        return self.replace(config=self.config.replace(plan_steps=0, plan_starts=0))

    def __call__(self, obs: jax.Array) -> jax.Array:
        """obs (..., obs_size) raw -> action (..., action_size) rad (with
        PolicyConfig.plan_steps, the landing of that many imagined train-driver steps)."""
        steps = self.config.policy.plan_steps
        if steps:  # the policy itself, without the plan, is what the plan imagines
            starts = self.config.policy.plan_starts
            act = self.one_step()
            if starts:
                return restarted_landing(act, obs, steps, starts)
            return planned_landing(act, obs, steps)
        return self.distribution(obs)[0]

    def distribution(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Gaussian (mean, log_std), each (..., action_size), for stochastic use."""
        mean, log_std, _ = forward(
            self.network, self.params, self.obs_stats, obs, self.config.ppo.obs_clip
        )
        return mean, log_std


def planned_landing(act: Any, obs: jax.Array, steps: int) -> jax.Array:
    """The joint targets a MARA policy `act` (raw obs (N, obs_size) -> targets) reaches in
    `steps` imagined steps of the train driver from `obs` (..., 12 or 16: q, e,
    [quat_err,] v), on the nominal arm (PolicyConfig.plan_steps): the target pose is
    read off the observation (p = p_tcp(q) - e, quat = conj(quat_err) (x) quat_tcp(q));
    each step q' = clip(act(obs), joint limits), then obs' at q' with the TCP velocity
    J_pos(q') (q' - q) / control_dt, as the train driver reports it (no contact check).
    Batch-first, the loop outermost with its values in the carry, `act` (a Policy, or a
    function wrapped as a pytree) included, so that jax2onnx exports it."""
    from mara_mjx.envs.base import EnvConfig
    from mara_mjx.envs.task_space import joint_ranges, nominal_chain

    chain = nominal_chain()
    lo, hi = (np.asarray(x, np.float32) for x in joint_ranges())  # numpy: constants in ONNX
    dt = np.float32(EnvConfig.control_dt)
    tcp = jnp.vectorize(chain.tcp, signature="(6)->(3),(4)")
    jac = jnp.vectorize(chain.jacobian, signature="(6)->(6,6)")
    orientation = obs.shape[-1] == 16
    q0 = obs[..., :6]
    target_pos, target_quat = _target(obs, q0, tcp)

    def body(_, carry):
        o, q, target_pos, target_quat, act = carry
        a = jnp.clip(act(o), lo, hi)
        pos, quat = tcp(a)
        v = jnp.einsum("...ij,...j->...i", jac(a)[..., :3, :], (a - q) / dt)
        o = _observation(a, pos, quat, v, target_pos, target_quat, orientation)
        return o, a, target_pos, target_quat, act

    if not isinstance(act, Policy):
        act = jax.tree_util.Partial(act)
    return jax.lax.fori_loop(0, steps, body, (obs, q0, target_pos, target_quat, act))[1]


def _target(obs: jax.Array, q0: jax.Array, tcp: Any) -> tuple[jax.Array, jax.Array]:
    """(position, quaternion) of the target a MARA observation (..., 12 or 16) reports at
    its own joints q0 (its first 6 entries) on the nominal arm (`tcp`: joints -> the TCP's
    position, quaternion):
    p = p_tcp(q) - e, quat = conj(quat_err) (x) quat_tcp(q); without an orientation in
    the observation, the TCP's quaternion (carried, unused)."""
    from mara_mjx.envs.geometry import quat_conj, quat_mul

    pos0, quat0 = tcp(q0)
    orientation = obs.shape[-1] == 16
    return pos0 - obs[..., 6:9], (
        quat_mul(quat_conj(obs[..., 9:13]), quat0) if orientation else quat0
    )


def _observation(q, pos, quat, v, target_pos, target_quat, orientation: bool) -> jax.Array:
    """The MARA observation (q, e, [quat_err,] v) at joints q, where the nominal TCP is at
    `pos`, `quat` and moves at v, toward the target (`_target`'s), quat_err only with an
    `orientation`, as the train driver reports it."""
    from mara_mjx.envs.geometry import quat_conj, quat_mul

    parts = [q, pos - target_pos]
    if orientation:
        parts.append(quat_mul(quat, quat_conj(target_quat)))
    return jnp.concatenate([*parts, v], -1)


def start_postures(k: int) -> np.ndarray:
    """(k, 6) rad: PolicyConfig.plan_starts' other starting postures, uniform within 0.8 x
    the joint ranges from numpy's default_rng(0) (the first k of any larger set)."""
    from mara_mjx.envs.task_space import joint_ranges

    lo, hi = (np.asarray(x, np.float64) for x in joint_ranges())
    return np.random.default_rng(0).uniform(0.8 * lo, 0.8 * hi, size=(k, 6)).astype(np.float32)


def landing_error(
    q: jax.Array, target_pos: jax.Array, target_quat: jax.Array, orientation: bool
) -> jax.Array:
    """The error restarted_landing ranks landings by: joints q (..., 6) against a target
    (position (..., 3) m, quaternion (..., 4)) on the nominal arm, the largest of the
    TCP's position error per axis (mm) and, with an `orientation`, the angle of the
    rotation between the TCP's and the target's (deg) -> (...,)."""
    from mara_mjx.envs.geometry import quat_conj, quat_mul
    from mara_mjx.envs.task_space import nominal_chain

    pos, quat = jnp.vectorize(nominal_chain().tcp, signature="(6)->(3),(4)")(q)
    err = 1000.0 * jnp.max(jnp.abs(pos - target_pos), axis=-1)
    if orientation:
        rot = quat_mul(quat, quat_conj(target_quat))
        half = jnp.clip(jnp.linalg.norm(rot[..., 1:], axis=-1), 0.0, 1.0)
        err = jnp.maximum(err, jnp.degrees(2.0 * jnp.arcsin(half)))
    return err


def path_clearance(q0: jax.Array, q1: jax.Array, points: int) -> jax.Array:
    """(..., 6), (..., 6) rad -> (...,) m: the smallest clearance (envs/clearance.py) of
    the nominal arm along the servos' path from q0 to q1 (every joint moving toward its
    own target at the same speed, so the joint with the farthest to go arrives last), at
    `points` evenly spaced instants after q0, q1 the last. Batch-first with the loop
    outermost and its values in the carry (jax2onnx exports it)."""
    from mara_mjx.envs.clearance import clearance

    delta = q1 - q0
    span = jnp.max(jnp.abs(delta), axis=-1, keepdims=True)

    def body(i, carry):
        low, q0, delta, span = carry
        f = (i + 1).astype(q0.dtype) / np.float32(points)
        q = q0 + jnp.clip(delta, -f * span, f * span)
        return jnp.minimum(low, clearance(q)), q0, delta, span

    # (the landing's own clearance first: a shape ONNX can trace under a symbolic batch)
    return jax.lax.fori_loop(0, points - 1, body, (clearance(q1), q0, delta, span))[0]


def restarted_landing(act: Any, obs: jax.Array, steps: int, starts: int) -> jax.Array:
    """PolicyConfig.plan_starts: `planned_landing(act, obs, steps)` where it ends within
    PLAN_KEEP_MM of the target read off `obs`; else, of the landings of PLAN_START_STEPS
    imagined steps from each of `start_postures(starts)` toward the same target, of those
    within PLAN_KEEP_MM whose servos' path from the observed joints keeps PLAN_CLEAR_MM
    from every contact (or the clearance the arm has now, where that is less;
    `path_clearance` at PLAN_PATH_POINTS points), the one with the shortest path (the
    smallest largest joint move); else, where it reaches and is clear so, the own landing's
    other wrist branch solved by the IK step alone (`task_space.wrist_flip`, `ik_landing`);
    else the own landing (errors: `landing_error`, with the orientation where `obs` has
    one).

    Only the rows whose own landing misses are restarted, PLAN_RESTART_GROUP of them at a
    time (fewer where the batch is smaller), in a while loop that ends when none is left
    (none: no iteration): a group's rows are gathered and the choices put back by one-hot
    products, exact, with static shapes, so that a batch of 1,000 arms with one missing
    costs one group, not 1,000 restarts. Each group's K restarts run side by side (one
    imagined loop over K x the group). Batch-first like planned_landing (jax2onnx exports
    it: a Loop whose trip count is the number of groups)."""
    from mara_mjx.envs.task_space import nominal_chain
    from mara_mjx.ppo.parametrisation import PLAN_KEEP_MM, PLAN_RESTART_GROUP

    tcp = jnp.vectorize(nominal_chain().tcp, signature="(6)->(3),(4)")
    orientation = obs.shape[-1] == 16
    size = obs.shape[-1]
    flat = obs.reshape(-1, size)  # (B, obs): leading axes flattened
    q0 = flat[:, :6]
    target_pos, target_quat = _target(flat, q0, tcp)
    own = planned_landing(act, flat, steps)
    own_err = landing_error(own, target_pos, target_quat, orientation)
    batch = flat.shape[0]
    group = min(PLAN_RESTART_GROUP, batch) if isinstance(batch, int) else PLAN_RESTART_GROUP
    # what a group needs of its rows, gathered in one product (non-finite entries zeroed:
    # 0 x NaN would spread a diverged row into every group)
    rows = jnp.concatenate([flat, own], axis=1)
    rows = jnp.where(jnp.isfinite(rows), rows, 0.0)
    if not isinstance(act, Policy):
        act = jax.tree_util.Partial(act)

    def body(carry):
        best, todo, rows, act = carry
        # the first `group` rows still to do: row r is the slot-th, slot = its rank
        slot = jnp.cumsum(todo.astype(jnp.int32)) - 1
        pick = todo[None, :] & (slot[None, :] == jnp.arange(group)[:, None])  # (group, B)
        pick = pick.astype(rows.dtype)
        valid = jnp.any(pick > 0, axis=1)
        mine = pick @ rows  # (group, obs + 6): each slot's row (zeros where none is left)
        o, g_own = mine[:, :size], mine[:, size:]
        choice = _restart_choice(act, o, g_own, starts, orientation)
        choice = jnp.where(valid[:, None] & jnp.isfinite(choice), choice, g_own)
        hit = jnp.any(pick > 0, axis=0)
        best = jnp.where(hit[:, None], pick.T @ choice, best)
        return best, todo & ~hit, rows, act

    todo = own_err > PLAN_KEEP_MM  # (NaN: not restarted)
    best = jax.lax.while_loop(lambda c: jnp.any(c[1]), body, (own, todo, rows, act))[0]
    return best.reshape(obs.shape[:-1] + (6,))


def _restart_choice(
    act: Any, obs: jax.Array, own: jax.Array, starts: int, orientation: bool
) -> jax.Array:
    """restarted_landing's choice for a group of rows (G, obs) whose own landings `own`
    (G, 6) miss: the K = `starts` restarts' landings imagined side by
    side (the K starting postures stacked in front of the group and flattened into it,
    one loop of PLAN_START_STEPS: on a GPU the decision's sequential depth; in ONNX one
    Loop), the shortest clear one within PLAN_KEEP_MM, else the last resort (the other
    wrist branch), else `own` -> (G, 6)."""
    from mara_mjx.envs.clearance import clearance
    from mara_mjx.envs.task_space import ik_landing, nominal_chain, wrist_flip
    from mara_mjx.ppo.parametrisation import (
        PLAN_CLEAR_MM,
        PLAN_KEEP_MM,
        PLAN_PATH_POINTS,
        PLAN_START_STEPS,
    )

    tcp = jnp.vectorize(nominal_chain().tcp, signature="(6)->(3),(4)")
    q0 = obs[:, :6]
    target_pos, target_quat = _target(obs, q0, tcp)
    g = q0.shape[0]

    def stacked(x):  # (G, n) -> (K x G, n), the same for every start
        return jnp.broadcast_to(x, (starts,) + x.shape).reshape(starts * g, x.shape[-1])

    q = jnp.broadcast_to(jnp.asarray(start_postures(starts))[:, None, :], (starts, g, 6))
    q = q.reshape(starts * g, 6)
    tp, tq = stacked(target_pos), stacked(target_quat)
    o = _observation(q, *tcp(q), jnp.zeros_like(tp), tp, tq, orientation)
    lands = planned_landing(act, o, PLAN_START_STEPS)
    errs = landing_error(lands, tp, tq, orientation).reshape(starts, g)
    lands = lands.reshape(starts, g, 6)
    # clear: the servos' path from here to the landing keeps PLAN_CLEAR_MM (or the
    # clearance the arm has now, where that is less) from every contact
    need = jnp.minimum(np.float32(PLAN_CLEAR_MM / 1000.0), clearance(q0))
    here = q0 + 0 * lands  # (q0 in every start's row: a broadcast jax2onnx traces)
    clear = path_clearance(here, lands, PLAN_PATH_POINTS) >= need
    # of those, the shortest servos' path (the largest joint move): landings within
    # PLAN_KEEP_MM are all on the target, and ranking them by their error would be
    # decided by rounding (benchmarks/NOTES.md section 49)
    spans = jnp.max(jnp.abs(lands - q0), axis=-1)  # (K, G)
    best, best_span = own, jnp.zeros(own.shape[:-1], own.dtype)
    found = jnp.zeros(own.shape[:-1], bool)
    for i in range(starts):  # the first shortest clear landing within PLAN_KEEP_MM
        better = (errs[i] <= PLAN_KEEP_MM) & clear[i] & (~found | (spans[i] < best_span))
        best = jnp.where(better[..., None], lands[i], best)
        best_span = jnp.where(better, spans[i], best_span)
        found = found | better
    # where none reaches: the own landing's other wrist branch (`wrist_flip`: where the own
    # one is held at joint 4's stop, benchmarks/NOTES.md section 68), solved from there by
    # the IK step alone (the network may steer back to the branch it prefers), apart from
    # the K starts above, which so keep their shapes and bits
    land = ik_landing(wrist_flip(own), target_pos, target_quat if orientation else None,
                      PLAN_START_STEPS)  # fmt: skip
    take = ~found & (landing_error(land, target_pos, target_quat, orientation) <= PLAN_KEEP_MM)
    take = take & (path_clearance(q0, land, PLAN_PATH_POINTS) >= need)
    return jnp.where(take[..., None], land, best)  # (own where nothing clear reaches)


def rate_limited(policy: Any, max_step: Any, lower: Any = None, upper: Any = None) -> Any:
    """`policy` whose joint targets, clipped to [lower, upper] when given (as the env
    clips them), are moved toward the observed joints (obs[..., :A], the MARA
    observation's q), the whole displacement scaled by one factor, so that no joint is
    asked to move more than `max_step` rad (a float, or an array broadcasting against
    the batch, e.g. (E, 1) per episode): the direction in joint space is kept, where a
    servo-driven arm moving each joint at its own top speed would follow
    sign(displacement) instead. Non-finite targets pass through unchanged (the env
    counts and replaces them) and do not enter the scale. A pytree like `policy`
    (jax.tree_util.Partial)."""
    if isinstance(max_step, int | float) and not max_step > 0:
        raise ValueError(f"rate_limited: max_step={max_step!r} must be > 0 (rad per step)")
    bounds = None if lower is None else (jnp.asarray(lower), jnp.asarray(upper))
    return jax.tree_util.Partial(
        _rate_limited_call, policy, jnp.asarray(max_step, jnp.float32), bounds
    )


def _rate_limited_call(policy: Any, max_step: jax.Array, bounds: Any, obs: jax.Array):
    action = policy(obs)
    return limit_step(action, obs[..., : action.shape[-1]], max_step, bounds)


def limit_step(action: jax.Array, q: jax.Array, max_step: Any, bounds: Any = None) -> jax.Array:
    """`rate_limited`'s output stage for joint targets `action` at observed joints `q`."""
    max_step = jnp.asarray(max_step, jnp.float32)
    finite = jnp.isfinite(action)
    target = jnp.where(finite, action, q)
    if bounds is not None:
        target = jnp.clip(target, bounds[0], bounds[1])
    delta = target - q
    big = jnp.max(jnp.abs(delta), axis=-1, keepdims=True)
    limited = q + delta * jnp.minimum(1.0, max_step / jnp.maximum(big, 1e-12))
    return jnp.where(finite, limited, action)


def make_policy(
    checkpoint_or_params: Any,
    config: TrainConfig | PPOConfig | None = None,
    obs_stats: RunningStats | None = None,
) -> Policy:
    """The deterministic policy fn(obs) -> action from any of:

    * a checkpoint path (file, or a run folder: its newest checkpoint); config is read
      from the checkpoint;
    * a `RunnerState` (training state) with its `config`;
    * flax params of `ActorCritic` with their `config` (and `obs_stats` when
      config.ppo.normalize_obs);
    * a `Policy` (returned as is).
    """
    if isinstance(checkpoint_or_params, Policy):
        return checkpoint_or_params
    if isinstance(checkpoint_or_params, str | os.PathLike):
        return load_policy(checkpoint_or_params)
    if config is None:
        raise ValueError("make_policy needs the TrainConfig the params were trained with")
    config = as_train_config(config)
    params = checkpoint_or_params
    if hasattr(params, "params") and hasattr(params, "obs_stats"):  # RunnerState
        params, obs_stats = params.params, params.obs_stats
        axis = member_axis(checkpoint_or_params)
        if axis is not None:  # a population's policy is member 0's
            params, obs_stats = jax.tree.map(
                lambda x: jnp.take(x, 0, axis=axis), (params, obs_stats)
            )
    try:
        action_size = int(params["params"]["log_std"].shape[-1])
    except (KeyError, TypeError, AttributeError) as e:
        raise ValueError(
            "make_policy: params are not those of mara_mjx.ppo.ActorCritic "
            "(no params['params']['log_std'])"
        ) from e
    if config.ppo.normalize_obs and obs_stats is None:
        raise ValueError(
            "make_policy: config.normalize_obs is true but no obs_stats were given; the policy "
            "would see unnormalised observations"
        )
    return Policy(
        params=params,
        obs_stats=obs_stats if config.ppo.normalize_obs else None,
        config=config,
        action_size=action_size,
    )


def load_policy(path: str | os.PathLike) -> Policy:
    """The deterministic `Policy` of a checkpoint file or run folder (its newest readable
    checkpoint)."""
    return policy_from_checkpoint(*load_checkpoint(find_checkpoint(path)))


def policy_from_checkpoint(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Policy:
    """The deterministic `Policy` from `mara_mjx.ppo.checkpoint.load_checkpoint` output.
    CheckpointError where its parameters or observation statistics are not finite (a
    diverged run: its NaN actions would be replaced by holding the pose, and an
    evaluation would print a normal-looking table). Every CLI that loads a policy
    (evaluate, play, export, a --seeds evaluation) comes through here."""
    try:
        config = TrainConfig.from_meta(meta)  # either layout (a pre-split flat "ppo" too)
    except (TypeError, ValueError) as e:
        raise CheckpointError(f"checkpoint holds an invalid PPO config: {e}") from e
    network = make_network(config, meta["action_size"])
    obs = jax.ShapeDtypeStruct((meta["observation_size"],), jnp.float32)
    template = jax.eval_shape(network.init, jax.random.key(0), obs, obs)
    if config.curriculum.population > 1:  # a population's policy is member 0's (members)
        arrays = {
            k: (v[0] if k.startswith(("params/", "obs_stats/")) else v) for k, v in arrays.items()
        }
    check_finite_arrays(arrays)
    params = arrays_to_state(arrays, template, prefix="params/")
    stats = None
    if config.ppo.normalize_obs:
        stats = arrays_to_state(arrays, RunningStats.create(meta["observation_size"]), "obs_stats/")
    return Policy(params=params, obs_stats=stats, config=config, action_size=meta["action_size"])


def check_finite_arrays(arrays: dict[str, np.ndarray]) -> None:
    """CheckpointError naming the policy arrays (params/..., obs_stats/...) of a
    checkpoint that hold NaN or inf."""
    bad = [
        name
        for name, value in arrays.items()
        if name.startswith(("params/", "obs_stats/"))
        and np.issubdtype(np.asarray(value).dtype, np.inexact)
        and not np.all(np.isfinite(value))
    ]
    if bad:
        shown = ", ".join(bad[:3]) + (f" and {len(bad) - 3} more" if len(bad) > 3 else "")
        raise CheckpointError(
            f"the checkpoint's policy is not finite (NaN or inf in {shown}): the run diverged; "
            "use an earlier checkpoint of the run"
        )
