"""PPO for thousands of environments per device, PureJaxRL style.

    trainer = make_train(env, PPOConfig(num_envs=2048, num_steps=32), updates_per_call=10)
    # or a TrainConfig (PPOConfig, PolicyConfig, CurriculumConfig), e.g. PRESETS["default"]
    state = trainer.init(jax.random.key(0))
    while done < trainer.num_updates:
        n = min(trainer.updates_per_call, trainer.num_updates - done)
        state, metrics = trainer.run(state, n)   # n updates in one jitted lax.scan
        done += n                                 # host: progress, logs, checkpoints

One update, top to bottom:
  1. rollout: `num_steps` steps of all envs with actions sampled from the Gaussian policy
     (a lax.scan over BatchedEnv.step, which auto-resets ended episodes), plus one extra
     step with the deterministic action (the saved policy's; with the reach probe below,
     the Gaussian mean) whose metrics measure accuracy, its state discarded ("probe");
  2. values of obs and of final_obs (pre-reset) -> GAE with truncation bootstrap (losses.py);
  3. `update_epochs` passes over the shuffled batch in `num_minibatches` Adam steps of the
     clipped PPO loss (losses.py); minibatches are stratified by environment (each holds
     num_steps / num_minibatches random samples of every env when that divides), so that
     over several devices each device trains on its own envs' samples (see sgd below);
  4. observation statistics merged with the rollout's observations (if normalize_obs); the
     rollout and the loss of this update both used the statistics from before it.
With `curriculum.probe_reach_steps`, a call ends with the saved policy's deterministic
rollout from the reset (`reach_error_mm`), in `run` or apart (`Trainer.probe`).

Env step counts never live in a device integer: the host derives them as Python ints from
the update count (an int32 that stays below 2^31 / (epochs * minibatches), checked in
PPOConfig).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.extend.core import jaxpr_as_fun
from jax.flatten_util import ravel_pytree

from mara_mjx.envs.batched import BatchedEnv, BatchedState
from mara_mjx.ppo.config import PPOConfig, TrainConfig, for_env
from mara_mjx.ppo.curriculum import capped_envs, make_schedule
from mara_mjx.ppo.losses import bound_loss, gae, ppo_loss
from mara_mjx.ppo.members import population
from mara_mjx.ppo.metrics import probe_metric_summary, reach_probe, reach_row, rollout_metrics
from mara_mjx.ppo.networks import (
    ActorCritic,
    RunningStats,
    canonical_quat,
    forward,
    gaussian_entropy,
    gaussian_log_prob,
    ik_inputs,
    make_network,
    update_stats,
)
from mara_mjx.ppo.optim import make_lr_schedule, make_optimizer, stratified_minibatches
from mara_mjx.ppo.teacher import imitation_labeller, imitation_loss, rollout_sigma
from mara_mjx.runtime import sharding


@struct.dataclass
class RunnerState:
    """Everything an exact resume needs (saved whole in checkpoints)."""

    params: Any  # flax params of ActorCritic
    opt_state: optax.OptState
    obs_stats: RunningStats
    env_state: BatchedState
    key: jax.Array
    update: jax.Array  # () int32, PPO updates done
    # CurriculumConfig.population > 1: (K,) mean training reward per step of each member since
    # the last exploit step, summed over updates; every other leaf has a (K,) member axis.
    fitness: Any = None
    # CurriculumConfig.teacher: the teacher's deployed Policy (never trained; in the state
    # so that --seeds gives each seed its own and a checkpoint resumes whole), else None.
    teacher: Any = None


class Transition(NamedTuple):
    """One rollout step of all envs; a rollout stacks them to (T, N, ...)."""

    obs: jax.Array  # (N, obs) observation acted on (raw, not normalised)
    action: jax.Array  # (N, A) rad, sampled joint targets (before the env clips them)
    log_prob: jax.Array  # (N,)
    reward: jax.Array  # (N,)
    terminated: jax.Array  # (N,) bool
    truncated: jax.Array  # (N,) bool
    final_obs: jax.Array  # (N, obs) observation the step produced, before any auto-reset
    episode_return: jax.Array  # (N,) return of the episode that ended here, else 0
    metrics: dict[str, jax.Array]  # env metrics of the step
    ik: Any = None  # networks.ik_inputs of obs (ik_prior), computed once per sample
    teacher_action: Any = None  # (N, A) rad, the imitation label at obs (teacher.py)


class Batch(NamedTuple):
    """Training data of one update: (T, N, ...) time-first, as the rollout made it."""

    obs: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    advantages: jax.Array
    returns: jax.Array
    ik: Any = None  # networks.ik_inputs of obs (ik_prior), from the rollout
    teacher_action: Any = None  # the imitation label at obs (CurriculumConfig.teacher)


class Trainer(NamedTuple):
    """What `make_train` returns: jitted `init` and `run`, and the sizes the host needs."""

    config: TrainConfig
    """The resolved config (for_env) the trainer compiled."""
    env: BatchedEnv
    network: ActorCritic
    init: Callable[[jax.Array], RunnerState]
    run: Callable[[RunnerState, int], tuple[RunnerState, dict[str, jax.Array]]]
    """run(state, n): n <= updates_per_call updates; metrics have a leading
    (updates_per_call,) axis whose first n rows are valid (metrics["valid"])."""
    updates_per_call: int
    num_updates: int
    steps_per_update: int
    teacher: Any = None
    """The teacher Policy init puts in the state (CurriculumConfig.teacher), else None."""
    probe: Callable[[RunnerState, int], jax.Array] | None = None
    """make_train's probe_apart: probe(state, n) -> the reach_error_mm column of a call of
    n updates (`metrics.reach_row`), its own program, left out of `run`; else None."""


def make_train(
    env: Any,
    train_config: PPOConfig | TrainConfig,
    updates_per_call: int = 1,
    devices: int | None = None,
    teacher: Any = None,
    probe_apart: bool = False,
) -> Trainer:
    """PPO on `num_envs` copies of `env` (any env BatchedEnv can wrap), over `devices`
    devices (None or 0: all; see mara_mjx.runtime.sharding): environments, rollout and
    minibatches sharded along the env axis, parameters replicated, gradients averaged by
    one all-reduce per minibatch. A PPOConfig alone trains the default policy
    parametrisation without curriculum (TrainConfig(ppo=config)). `teacher`: the
    Policy (mara_mjx.ppo.teacher.load_teacher) a run with CurriculumConfig.teacher
    imitates instead of maximising the reward. `probe_apart`: the reach probe in its own
    program, `Trainer.probe`, run by the caller after `run` (the train CLI compiles the two
    side by side, ppo.warmup); not with a population (its `run` probes before exploiting)."""
    train_config = for_env(train_config, env)
    config, curriculum = train_config.ppo, train_config.curriculum
    if bool(curriculum.teacher) != (teacher is not None):
        raise ValueError(
            "imitation needs both CurriculumConfig.teacher (the teacher's path, recorded) and "
            "make_train(..., teacher=mara_mjx.ppo.teacher.load_teacher(path, env_name))"
            if curriculum.teacher
            else "make_train got a teacher but the config's teacher is '': set it to the "
            "teacher's path"
        )
    benv = BatchedEnv(env, config.num_envs, devices=devices)
    mesh = benv.mesh
    network = make_network(train_config, benv.action_size, training=True)
    saved = make_network(train_config, benv.action_size)  # the saved policy (the probe's)
    # det_* step: the saved policy, unless the reach probe measures it (NOTES s. 70: 37% of run)
    det_network = saved if curriculum.probe_reach_steps == 0 else network
    optimizer = make_optimizer(config)
    lr_at_update = make_lr_schedule(config)
    obs_size = benv.observation_size  # hidden_obs within it: checked by for_env
    clip = config.obs_clip
    schedule = make_schedule(curriculum, env, benv, config.num_updates)

    def stats_in_use(state: RunnerState) -> RunningStats | None:
        return state.obs_stats if config.normalize_obs else None

    def policy(params: Any, stats: RunningStats | None, obs: jax.Array, ik: Any = None):
        return forward(network, params, stats, obs, config.obs_clip, ik)

    def init(key: jax.Array) -> RunnerState:
        key, net_key, env_key = jax.random.split(key, 3)
        obs = jnp.zeros((obs_size,), jnp.float32)
        params = network.init(net_key, obs, obs)
        params = sharding.replicate(params, mesh)
        env_state, key = schedule.stagger(benv.reset(env_key, schedule.initial_params()), key)
        return RunnerState(
            params=params,
            opt_state=optimizer.init(params),
            obs_stats=RunningStats.create(obs_size),
            env_state=env_state,
            key=key,
            update=jnp.zeros((), jnp.int32),
            teacher=None if teacher is None else sharding.replicate(teacher, mesh),
        )

    # ------------------------------------------------------------------ rollout
    capped = capped_envs(curriculum, config.num_envs)  # None unless asked for

    lower = jnp.asarray(getattr(env, "joint_lower", -jnp.inf), jnp.float32)
    upper = jnp.asarray(getattr(env, "joint_upper", jnp.inf), jnp.float32)
    imitation_label = imitation_labeller(benv.step, lower, upper, curriculum)

    def rollout(
        params: Any,
        stats: RunningStats | None,
        env_state: BatchedState,
        key: jax.Array,
        teacher: Any = None,
    ) -> tuple[BatchedState, Transition, dict[str, jax.Array]]:
        """num_steps sampled steps, then the deterministic probe step (state discarded)."""

        spread = curriculum.imitation_spread if teacher is not None else 0.0

        def step(carry, t):
            env_state, key = carry
            key, noise_key = jax.random.split(key)
            ik = ik_inputs(network, env_state.obs)  # once per sample (the IK step: ik_prior)
            mean, log_std, _ = policy(params, stats, env_state.obs, ik)
            sigma = rollout_sigma(log_std, spread)  # imitation may widen it (log_prob
            # below stays the student's own: only PPO's loss, unused by imitation, reads it)
            sample = mean + sigma * jax.random.normal(noise_key, mean.shape)
            probe = t == config.num_steps
            probe_mean = mean
            if det_network != network:  # training-only parts: the saved policy (its step)
                probe_mean = jax.lax.cond(
                    probe,
                    lambda: forward(det_network, params, stats, env_state.obs, clip)[0],
                    lambda: mean,
                )
            action = jnp.where(probe, probe_mean, sample)
            env_action, q = action, env_state.obs[..., : action.shape[-1]]  # observed joints
            step_max = train_config.policy.max_joint_step
            if step_max > 0.0:  # samples stay within m of the observed joints
                env_action = jnp.clip(action, q - step_max, q + step_max)
            if capped is not None:  # a share of the envs moves at a servo's pace
                env_action = capped(env_action, q, probe)
            next_state = benv.step(env_state, env_action)
            transition = Transition(
                obs=env_state.obs,
                action=action,
                log_prob=gaussian_log_prob(mean, log_std, action),
                reward=next_state.reward,
                terminated=next_state.terminated,
                truncated=next_state.truncated,
                final_obs=next_state.final_obs,
                episode_return=next_state.episode_return,
                metrics=next_state.metrics,
                ik=ik,
                teacher_action=None if teacher is None else imitation_label(teacher, env_state),
            )
            env_state = jax.tree.map(
                lambda old, new: jnp.where(probe, old, new), env_state, next_state
            )
            return (env_state, key), transition

        (env_state, _), traj = jax.lax.scan(
            step, (env_state, key), jnp.arange(config.num_steps + 1)
        )
        probe_metrics = jax.tree.map(lambda x: x[-1], traj.metrics)
        traj = sharding.constrain(jax.tree.map(lambda x: x[:-1], traj), mesh, axis=1)
        return env_state, traj, probe_metrics

    # ---------------------------------------------------------------------- SGD
    def loss_fn(params: Any, stats: RunningStats | None, mb: Batch):
        mean, log_std, value = policy(params, stats, mb.obs, mb.ik)
        total, info = ppo_loss(
            gaussian_log_prob(mean, log_std, mb.action),
            value,
            gaussian_entropy(log_std),
            mb.log_prob,
            mb.value,
            mb.advantages,
            mb.returns,
            clip_eps=config.clip_eps,
            vf_coef=config.vf_coef,
            ent_coef=config.ent_coef,
            clip_value=config.clip_value,
            normalize_advantages=False,  # done per minibatch over all devices in sgd()
        )
        if mb.teacher_action is not None:  # imitation: the teacher's label, not the reward
            # is the loss and the policy's (PPO's, untrained, overflows: NOTES section 58)
            total = imitation_loss(mean, log_std, mb.teacher_action)
            info = info._replace(total=total, policy=total)
        if curriculum.bound_coef > 0.0:  # keep the mean where the env does not clip it
            total = total + curriculum.bound_coef * bound_loss(mean, lower, upper)
        return total, info

    # SGD runs per device on its own envs (stratified_minibatches); every device's share of
    # envs must split evenly into the minibatches' env groups.
    env_groups = math.lcm(config.num_minibatches, config.num_steps) // config.num_steps
    n_devices = 1 if mesh is None else mesh.size
    if (config.num_envs // n_devices) % env_groups:
        raise ValueError(
            f"num_minibatches={config.num_minibatches} with num_steps={config.num_steps} "
            f"cuts each minibatch from {env_groups} groups of environments, so the "
            f"{config.num_envs // n_devices} environments per device (num_envs="
            f"{config.num_envs} over {n_devices} devices) must be a multiple of "
            f"{env_groups}; choose num_minibatches dividing num_steps, more environments or "
            "fewer devices (--devices)"
        )

    def local_sgd(params: Any, opt_state: Any, stats: RunningStats | None, batch: Batch, keys):
        """update_epochs passes of num_minibatches Adam steps, on one device's shard of
        the (T, N) batch; every mean over the minibatch is a pmean of equal-sized parts."""

        def minibatch_step(carry, mb: Batch):
            params, opt_state = carry
            grads, info = jax.grad(loss_fn, has_aux=True)(params, stats, mb)
            # one flat all-reduce: the pytree's variadic one cost ~36 us/step, not ~6 (NOTES s. 10)
            flat, unravel = ravel_pytree(grads)
            grads = unravel(sharding.pmean(flat, mesh))
            updates, opt_state = optimizer.update(grads, opt_state, params)
            params = optax.apply_updates(params, updates)
            return (params, opt_state), (info, optax.tree.norm(grads))

        def epoch(carry, env_keys: jax.Array):
            T, M = config.num_steps, config.num_minibatches
            order = jax.vmap(lambda k: jax.random.permutation(k, T))(env_keys).T  # (T, n)
            minibatches = jax.tree.map(lambda x: stratified_minibatches(x, order, M), batch)
            if config.normalize_advantages:  # over each whole minibatch, all devices
                adv = minibatches.advantages
                mean = sharding.pmean(adv.mean(axis=1), mesh)[:, None]
                var = sharding.pmean(jnp.square(adv - mean).mean(axis=1), mesh)[:, None]
                minibatches = minibatches._replace(advantages=(adv - mean) / (jnp.sqrt(var) + 1e-8))
            return jax.lax.scan(minibatch_step, carry, minibatches)

        (params, opt_state), (info, grad_norm) = jax.lax.scan(epoch, (params, opt_state), keys)
        return params, opt_state, sharding.pmean(info, mesh), grad_norm

    def sgd(params: Any, opt_state: Any, stats: RunningStats | None, batch: Batch, key):
        """local_sgd on every device; a permutation key per (epoch, env), so the shuffle
        is the same however the envs are spread over devices."""
        keys = jax.random.split(key, (config.update_epochs, config.num_envs))
        per_device = sharding.map_envs(
            local_sgd, mesh, in_axes=(None, None, None, 1, 1), out_axes=None
        )
        return per_device(params, opt_state, stats, batch, keys)

    # ------------------------------------------------------------------- update
    def update(state: RunnerState) -> tuple[RunnerState, dict[str, jax.Array]]:
        key, rollout_key, sgd_key = jax.random.split(state.key, 3)
        stats = stats_in_use(state)
        env_state = schedule.rollout_state(state.env_state, state.update)
        env_state, traj, probe = rollout(state.params, stats, env_state, rollout_key, state.teacher)

        reward = schedule.shaped_reward(traj.reward, traj, env_state, state.update)
        _, _, value = policy(state.params, stats, traj.obs, traj.ik)
        _, _, final_value = policy(state.params, stats, traj.final_obs)
        next_value = final_value * (1.0 - traj.terminated.astype(jnp.float32))
        done = traj.terminated | traj.truncated
        advantages, returns = gae(
            reward * config.reward_scale,
            value,
            next_value,
            done,
            config.gamma,
            config.gae_lambda,
        )
        batch = Batch(
            obs=traj.obs,
            action=traj.action,
            log_prob=traj.log_prob,
            value=value,
            advantages=advantages,
            returns=returns,
            ik=traj.ik,
            teacher_action=traj.teacher_action,
        )
        params, opt_state, info, grad_norm = sgd(
            state.params, state.opt_state, stats, batch, sgd_key
        )
        obs_stats = state.obs_stats
        if config.normalize_obs:
            obs_stats = update_stats(obs_stats, canonical_quat(traj.obs, network.quat_index))

        metrics = {
            **rollout_metrics(traj, done),
            **probe_metric_summary(probe),
            "policy_loss": info.policy.mean(),
            "value_loss": info.value.mean(),
            "loss": info.total.mean(),
            "entropy": info.entropy.mean(),
            "approx_kl": info.approx_kl.mean(),
            "clip_frac": info.clip_frac.mean(),
            "grad_norm": grad_norm.mean(),
            "learning_rate": lr_at_update(state.update),
            "explained_variance": 1.0 - jnp.var(returns - value) / (jnp.var(returns) + 1e-8),
            "train_reward_mean": jnp.mean(reward),
            "valid": jnp.array(True),
        }
        new_state = RunnerState(
            params=params,
            opt_state=opt_state,
            obs_stats=obs_stats,
            env_state=env_state,
            key=key,
            update=state.update + 1,
            teacher=state.teacher,
        )
        return new_state, metrics

    def probe(state: RunnerState) -> jax.Array:  # CurriculumConfig.probe_reach_steps
        policy_of = lambda obs: forward(saved, state.params, stats_in_use(state), obs, clip)  # noqa: E731
        return reach_probe(benv.env, policy_of, curriculum.probe_reach_steps)

    probing = curriculum.probe_reach_steps > 0  # (the reach probe: in run, or apart)
    apart = probing and probe_apart and curriculum.population == 1

    def run(state: RunnerState, num_updates: jax.Array) -> tuple[RunnerState, dict]:
        """min(num_updates, updates_per_call) updates in one lax.scan, the other iterations
        skipped (lax.cond): any n in one program. `update` is traced once, its jaxpr giving
        skip's shapes and the cond's branch (a second trace cost 1-2 s of a CPU cold start)."""
        jaxpr, out = jax.make_jaxpr(update, return_shape=True)(state)
        shapes, out_tree = out[1], jax.tree.structure(out)

        def traced_update(state: RunnerState):
            return jax.tree.unflatten(out_tree, jaxpr_as_fun(jaxpr)(*jax.tree.leaves(state)))

        def skip(state: RunnerState):
            nan = {k: jnp.full(v.shape, jnp.nan, v.dtype) for k, v in shapes.items()}
            return state, {**nan, "valid": jnp.array(False)}

        def body(state: RunnerState, i: jax.Array):
            return jax.lax.cond(i < num_updates, traced_update, skip, state)

        state, metrics = jax.lax.scan(body, state, jnp.arange(updates_per_call))
        if probing and not apart:  # the saved policy from the reset, on the last row
            metrics["reach_error_mm"] = reach_row(probe(state), num_updates, updates_per_call)
        return state, metrics

    if curriculum.population > 1:
        if mesh is not None:
            raise ValueError(
                f"population={curriculum.population} trains its members on one device: "
                "use --devices 1 (several devices can run several seeds: --seeds)"
            )
        init, run = population(init, run, train_config)

    donate = () if jax.default_backend() == "cpu" else (0,)
    return Trainer(
        config=train_config,
        env=benv,
        network=network,
        init=jax.jit(init),
        run=jax.jit(run, donate_argnums=donate),
        updates_per_call=updates_per_call,
        num_updates=config.num_updates,
        steps_per_update=config.batch_size,
        teacher=teacher,
        probe=jax.jit(lambda s, n: reach_row(probe(s), n, updates_per_call)) if apart else None,
    )
