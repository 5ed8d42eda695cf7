"""PPO for thousands of environments per device, PureJaxRL style.

    trainer = make_train(env, PPOConfig(num_envs=2048, num_steps=32), updates_per_call=10)
    state = trainer.init(jax.random.key(0))
    while done < trainer.num_updates:
        n = min(trainer.updates_per_call, trainer.num_updates - done)
        state, metrics = trainer.run(state, n)   # n updates in one jitted lax.scan
        done += n                                 # host: progress, logs, checkpoints

One update, top to bottom:
  1. rollout: `num_steps` steps of all envs with actions sampled from the Gaussian policy
     (a lax.scan over BatchedEnv.step, which auto-resets ended episodes), plus one extra
     step with the deterministic action (the Gaussian mean) whose metrics measure the
     current policy's accuracy and whose state is then discarded ("probe");
  2. values of obs and of final_obs (pre-reset) -> GAE with truncation bootstrap (losses.py);
  3. `update_epochs` passes over the shuffled batch in `num_minibatches` Adam steps of the
     clipped PPO loss (losses.py); minibatches are stratified by environment (each holds
     num_steps / num_minibatches random samples of every env when that divides), so that
     over several devices each device trains on its own envs' samples (see sgd below);
  4. observation statistics merged with the rollout's observations (if normalize_obs); the
     rollout and the loss of this update both used the statistics from before it.
With `probe_reach_steps`, a call of `run` ends with a deterministic rollout of the saved
policy from the reset (its accuracy once it has had the steps to reach: `reach_error_mm`).

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
from jax.flatten_util import ravel_pytree

from mara_mjx.envs.batched import BatchedEnv, BatchedState
from mara_mjx.envs.rewards import check_reward_value, collision_penalty
from mara_mjx.ppo.config import PPOConfig, for_env, reward_curriculum
from mara_mjx.ppo.losses import gae, ppo_loss
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
    # PPOConfig.population > 1: (K,) mean training reward per step of each member since
    # the last exploit step, summed over updates; every other leaf then has a leading
    # (K,) member axis. None (no leaf) for a single-member run.
    fitness: Any = None


PROBE_REACH_EPISODES = 4
"""PPOConfig.probe_reach_steps: episodes of the probe from the reset."""
PROBE_REACH_NOISE = 0.02
"""PPOConfig.probe_reach_steps: the probe's reset noise (rad), the paper evaluation's."""


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


class Batch(NamedTuple):
    """Training data of one update: (T, N, ...) time-first, as the rollout made it."""

    obs: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    advantages: jax.Array
    returns: jax.Array
    ik: Any = None  # networks.ik_inputs of obs (ik_prior), from the rollout


class Trainer(NamedTuple):
    """What `make_train` returns: jitted `init` and `run`, and the sizes the host needs."""

    config: PPOConfig
    env: BatchedEnv
    network: ActorCritic
    init: Callable[[jax.Array], RunnerState]
    run: Callable[[RunnerState, int], tuple[RunnerState, dict[str, jax.Array]]]
    """run(state, n): n <= updates_per_call updates; metrics have a leading
    (updates_per_call,) axis whose first n rows are valid (metrics["valid"])."""
    updates_per_call: int
    num_updates: int
    steps_per_update: int


def make_lr_schedule(config: PPOConfig) -> Callable[[jax.Array], jax.Array]:
    """Learning rate as a function of the update index (0-based), constant within an
    update as in baselines ppo2."""
    lr, num_updates = config.learning_rate, config.num_updates

    def schedule(update: jax.Array) -> jax.Array:
        update = jnp.asarray(update, jnp.float32)
        if config.lr_schedule == "linear":
            return lr * (1.0 - update / num_updates)
        if config.lr_schedule == "exp":
            return jnp.maximum(lr * jnp.exp(-config.lr_decay_rate * update), config.lr_floor)
        return jnp.full((), lr, jnp.float32)

    return schedule


def make_optimizer(config: PPOConfig) -> optax.GradientTransformation:
    """Global-norm clip then Adam (eps 1e-5), the rate following `make_lr_schedule`."""
    lr_at_update = make_lr_schedule(config)
    steps_per_update = config.update_epochs * config.num_minibatches
    return optax.chain(
        optax.clip_by_global_norm(config.max_grad_norm),
        optax.adam(lambda count: lr_at_update(count // steps_per_update), eps=config.adam_eps),
    )


def limit_penalty(q: jax.Array, lower: jax.Array, upper: jax.Array, soft: float) -> jax.Array:
    """sum_j relu(|q_j - c_j| - soft h_j) / ((1 - soft) h_j): 0 inside the soft range, 1 per
    joint at its limit (PPOConfig.train_limit_penalty); q (..., J)."""
    centre, half = (upper + lower) / 2, (upper - lower) / 2
    return jnp.sum(jax.nn.relu(jnp.abs(q - centre) - soft * half) / ((1 - soft) * half), -1)


def orientation_bonus(metrics: dict[str, jax.Array], config: PPOConfig) -> jax.Array:
    """w exp(-d / d0) exp(-theta / theta0) on non-colliding steps (PPOConfig.orientation_bonus)."""
    bonus = config.orientation_bonus * jnp.exp(
        -metrics["distance"] / config.orientation_bonus_distance
        - metrics["angle"] / config.orientation_bonus_angle
    )
    if "collided" in metrics:
        bonus = jnp.where(metrics["collided"] > 0, 0.0, bonus)
    return bonus


def make_train(
    env: Any, config: PPOConfig, updates_per_call: int = 1, devices: int | None = None
) -> Trainer:
    """PPO on `config.num_envs` copies of `env` (any env BatchedEnv can wrap), over
    `devices` devices (None or 0: all; see mara_mjx.runtime.sharding): environments, rollout and
    minibatches sharded along the env axis, parameters replicated, gradients averaged by
    one all-reduce per minibatch."""
    config = for_env(config, env)
    benv = BatchedEnv(env, config.num_envs, devices=devices)
    mesh = benv.mesh
    network = make_network(config, benv.action_size, training=True)
    saved = make_network(config, benv.action_size)  # the policy training saves (the probe's)
    optimizer = make_optimizer(config)
    lr_at_update = make_lr_schedule(config)
    obs_size = benv.observation_size  # hidden_obs within it: checked by for_env

    curriculum = reward_curriculum(config.train_reward)
    for name, value in curriculum.items():  # its start; the way to the env's own stays in
        try:  # range (the ranges are intervals)
            check_reward_value(name, value)
        except ValueError as e:
            raise ValueError(f"train_reward: {e}") from None
    until = max(1.0, config.train_reward_until * config.num_updates)

    def curriculum_frac(update: jax.Array) -> jax.Array:
        """How far the training-only curricula are toward the env's own reward: 0 at the
        first update, 1 from train_reward_until of the updates on (PPOConfig)."""
        return jnp.clip(update.astype(jnp.float32) / until, 0.0, 1.0)

    def curriculum_params(params: Any, frac: jax.Array) -> Any:
        """`params` with `train_reward` and `train_reset_noise` at `frac` (0: the
        PPOConfig values, 1: the env's own) of the way to the env's defaults."""
        own = benv.env.default_params
        if curriculum:
            reward = params.reward.replace(
                **{
                    k: jnp.full_like(
                        getattr(params.reward, k), v + frac * (getattr(own.reward, k) - v)
                    )
                    for k, v in curriculum.items()
                }
            )
            params = params.replace(reward=reward)
        if config.train_reset_noise > 0.0:
            v = config.train_reset_noise
            noise = jnp.full_like(params.reset_noise, v + frac * (own.reset_noise - v))
            params = params.replace(reset_noise=noise)
        return params

    def with_train_reward(env_state: BatchedState, update: jax.Array) -> BatchedState:
        """The rollout's reward hyperparameters and reset noise: `train_reward` and
        `train_reset_noise` moving linearly to the env's own over the first
        train_reward_until of the updates (PPOConfig)."""
        if not curriculum and config.train_reset_noise <= 0.0:
            return env_state
        params = curriculum_params(env_state.env_state.params, curriculum_frac(update))
        return env_state.replace(env_state=env_state.env_state.replace(params=params))

    def stats_in_use(state: RunnerState) -> RunningStats | None:
        return state.obs_stats if config.normalize_obs else None

    def policy(params: Any, stats: RunningStats | None, obs: jax.Array, ik: Any = None):
        return forward(network, params, stats, obs, config.obs_clip, ik)

    def initial_params() -> Any:
        """The env's default params, with `train_reset_noise` for the first episodes
        (None, the env's defaults, without it)."""
        if config.train_reset_noise <= 0.0:
            return None
        own = benv.env.default_params
        return own.replace(reset_noise=curriculum_params(own, 0.0).reset_noise)

    def init(key: jax.Array) -> RunnerState:
        key, net_key, env_key = jax.random.split(key, 3)
        obs = jnp.zeros((obs_size,), jnp.float32)
        params = network.init(net_key, obs, obs)
        params = sharding.replicate(params, mesh)
        env_state = benv.reset(env_key, initial_params())
        if config.stagger_episodes and hasattr(env_state.env_state, "step"):
            key, stagger_key = jax.random.split(key)
            horizon = benv.env.max_episode_steps
            steps = jax.random.randint(stagger_key, (config.num_envs,), 0, horizon, jnp.int32)
            inner = env_state.env_state.replace(step=steps)
            env_state = sharding.constrain(env_state.replace(env_state=inner), mesh)
        return RunnerState(
            params=params,
            opt_state=optimizer.init(params),
            obs_stats=RunningStats.create(obs_size),
            env_state=env_state,
            key=key,
            update=jnp.zeros((), jnp.int32),
        )

    # ------------------------------------------------------------------ rollout
    def rollout(
        params: Any, stats: RunningStats | None, env_state: BatchedState, key: jax.Array
    ) -> tuple[BatchedState, Transition, dict[str, jax.Array]]:
        """num_steps sampled steps, then the deterministic probe step (state discarded)."""

        def step(carry, t):
            env_state, key = carry
            key, noise_key = jax.random.split(key)
            ik = ik_inputs(network, env_state.obs)  # once per sample (the IK step: ik_prior)
            mean, log_std, _ = policy(params, stats, env_state.obs, ik)
            sample = mean + jnp.exp(log_std) * jax.random.normal(noise_key, mean.shape)
            probe = t == config.num_steps
            probe_mean = mean
            if network != saved:  # training-only parts: the probe measures the saved
                # policy (its step only)
                probe_mean = jax.lax.cond(
                    probe,
                    lambda: forward(saved, params, stats, env_state.obs, config.obs_clip)[0],
                    lambda: mean,
                )
            action = jnp.where(probe, probe_mean, sample)
            env_action = action
            if config.max_joint_step > 0.0:  # samples stay within m of the observed joints
                q = env_state.obs[..., : action.shape[-1]]
                env_action = jnp.clip(action, q - config.max_joint_step, q + config.max_joint_step)
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
    lower = jnp.asarray(getattr(env, "joint_lower", -jnp.inf), jnp.float32)
    upper = jnp.asarray(getattr(env, "joint_upper", jnp.inf), jnp.float32)

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
        if config.bound_coef > 0.0:  # keep the mean where the env does not clip it
            excess = jax.nn.relu(mean - upper) + jax.nn.relu(lower - mean)
            total = total + config.bound_coef * jnp.mean(jnp.sum(jnp.square(excess), axis=-1))
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
            # One all-reduce of one flat buffer. The pytree (13 arrays) made one variadic
            # all-reduce that cost ~36 us per step on 4 H200s instead of ~6 (NOTES s. 10).
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
        env_state = with_train_reward(state.env_state, state.update)
        env_state, traj, probe = rollout(state.params, stats, env_state, rollout_key)

        reward = traj.reward
        fade = 1.0 - curriculum_frac(state.update)  # the training-only penalties' weight
        if config.train_collision_penalty > 0.0 and "collided" in traj.metrics:
            own = env_state.env_state.params.reward  # (N,) leaves
            penalty = collision_penalty(
                traj.metrics["distance"], traj.metrics["collided"], own.delta, own.eta
            )
            reward = reward - fade * config.train_collision_penalty * penalty
        if config.orientation_bonus > 0.0:  # PPOConfig.orientation_bonus
            reward = reward + orientation_bonus(traj.metrics, config)
        if config.train_limit_penalty > 0.0 and hasattr(env, "joint_lower"):  # PPOConfig field
            q = traj.obs[..., : lower.shape[-1]]
            reward = reward - fade * config.train_limit_penalty * limit_penalty(
                q, lower, upper, config.train_limit_soft
            )
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
        )
        return new_state, metrics

    def run(state: RunnerState, num_updates: jax.Array) -> tuple[RunnerState, dict]:
        """min(num_updates, updates_per_call) updates in one lax.scan; the remaining
        iterations skip (lax.cond), so any n runs through one compiled program."""
        shapes = jax.eval_shape(update, state)[1]

        def skip(state: RunnerState):
            nan = {k: jnp.full(v.shape, jnp.nan, v.dtype) for k, v in shapes.items()}
            return state, {**nan, "valid": jnp.array(False)}

        def body(state: RunnerState, i: jax.Array):
            return jax.lax.cond(i < num_updates, update, skip, state)

        state, metrics = jax.lax.scan(body, state, jnp.arange(updates_per_call))
        if config.probe_reach_steps > 0:  # the saved policy from the reset, on the last row
            reach = reach_probe(state.params, stats_in_use(state))
            last = jnp.clip(num_updates, 1, updates_per_call) - 1
            metrics["reach_error_mm"] = jnp.full(updates_per_call, jnp.nan).at[last].set(reach)
        return state, metrics

    def reach_probe(params: Any, stats: RunningStats | None) -> jax.Array:
        """PPOConfig.probe_reach_steps: mean per-axis |e| (mm) of the saved (deterministic)
        policy after that many steps from the env's reset, PROBE_REACH_EPISODES episodes
        with the paper's evaluation noise (fixed keys: the same episodes every call)."""
        one = benv.env
        noisy = hasattr(getattr(one, "default_params", None), "reset_noise")
        env_params = one.make_params(reset_noise=PROBE_REACH_NOISE) if noisy else None
        keys = jax.random.split(jax.random.key(0), PROBE_REACH_EPISODES)
        env_state = jax.vmap(one.reset, in_axes=(0, None))(keys, env_params)

        def body(env_state, _):
            mean = forward(saved, params, stats, env_state.obs, config.obs_clip)[0]
            return jax.vmap(one.step)(env_state, mean), None

        env_state, _ = jax.lax.scan(body, env_state, None, length=config.probe_reach_steps)
        return 1000.0 * jnp.mean(env_state.metrics["position_error"])

    if config.population > 1:
        if mesh is not None:
            raise ValueError(
                f"population={config.population} trains its members on one device: "
                "use --devices 1 (several devices can run several seeds: --seeds)"
            )
        init, run = population(init, run, config)

    donate = () if jax.default_backend() == "cpu" else (0,)
    return Trainer(
        config=config,
        env=benv,
        network=network,
        init=jax.jit(init),
        run=jax.jit(run, donate_argnums=donate),
        updates_per_call=updates_per_call,
        num_updates=config.num_updates,
        steps_per_update=config.batch_size,
    )


def population(
    init: Callable[[jax.Array], RunnerState],
    run: Callable[[RunnerState, jax.Array], tuple[RunnerState, dict[str, jax.Array]]],
    config: PPOConfig,
):
    """`init` and `run` of one member turned into those of `config.population` members
    (vmapped) with population-based training's exploit step (PPOConfig.population).

    Member 0 starts from the run's key itself (so its start is a single run's), member k
    from fold_in(key, k). Exploit, at the end of a `run` call that crossed a multiple of
    the exploit interval (exploit_every of the updates) or reached the last update:
    members ranked by fitness (their summed mean training reward per step since the last
    exploit); slot i takes the i-th best for i < K - n, the n = max(1, floor(K *
    exploit_fraction)) remaining slots take copies of the n best; PRNG keys stay with
    their slots. So the exploit points fall on call boundaries (RunConfig.updates_per_call)
    and a run is reproducible for a given updates_per_call. The metrics are member 0's.

    The members are vmapped around the whole scanned `run`, as --seeds vmaps seeds."""
    K = config.population
    n_copy = min(K - 1, max(1, int(K * config.exploit_fraction)))
    interval = max(1, round(config.exploit_every * config.num_updates))

    def init_population(key: jax.Array) -> RunnerState:
        keys = jnp.stack([key] + [jax.random.fold_in(key, k) for k in range(1, K)])
        state = init_each(init, keys)
        return state.replace(fitness=jnp.zeros((K,), jnp.float32))

    def finite_members(state: RunnerState) -> jax.Array:
        """(K,) bool: the member's params and obs stats are all finite. A diverged member
        keeps a finite fitness (the env holds the pose for NaN actions and its reward
        stays finite), so only this ranks it last."""
        ok = jnp.ones((K,), bool)
        for x in jax.tree.leaves((state.params, state.obs_stats)):
            if jnp.issubdtype(x.dtype, jnp.inexact):
                ok &= jnp.all(jnp.isfinite(x.reshape(K, -1)), axis=1)
        return ok

    def exploit(state: RunnerState) -> RunnerState:
        fitness = jnp.nan_to_num(state.fitness, nan=-jnp.inf)
        fitness = jnp.where(finite_members(state), fitness, -jnp.inf)
        order = jnp.argsort(-fitness, stable=True)  # best first
        src = jnp.concatenate([order[: K - n_copy], order[:n_copy]])
        take = lambda tree: jax.tree.map(lambda x: x[src], tree)  # noqa: E731
        return state.replace(
            params=take(state.params),
            opt_state=take(state.opt_state),
            obs_stats=take(state.obs_stats),
            env_state=take(state.env_state),
            fitness=jnp.zeros_like(state.fitness),
        )

    def run_population(state: RunnerState, num_updates: jax.Array):
        before = state.update[0]
        members, metrics = jax.vmap(run, in_axes=(0, None))(
            state.replace(fitness=None), num_updates
        )
        gained = jnp.where(metrics["valid"], metrics["train_reward_mean"], 0.0).sum(axis=1)
        state = members.replace(fitness=state.fitness + gained)
        after = state.update[0]
        due = (after > before) & (
            (after // interval > before // interval) | (after == config.num_updates)
        )
        # a select, not lax.cond (the arrays are small)
        state = jax.tree.map(lambda new, old: jnp.where(due, new, old), exploit(state), state)
        out = jax.tree.map(lambda x: x[0], metrics)
        spread = jnp.max(metrics["train_reward_mean"], 0) - jnp.min(metrics["train_reward_mean"], 0)
        out["population_fitness_spread"] = spread
        return state, out

    return init_population, run_population


def member_axis(state: RunnerState) -> int | None:
    """The member axis of a (possibly seed-batched) population RunnerState, else None."""
    return None if state.fitness is None else jnp.ndim(state.fitness) - 1


class SeedTrainer(NamedTuple):
    """`num_seeds` independent runs of one Trainer in one jitted program (vmap over a
    leading seed axis of the RunnerState; seed axis sharded over the devices when there
    are several and they divide it). Seed i uses key(seeds[i]), as a single run with
    PPOConfig.seed = seeds[i] does, so its results match that run up to floating-point
    reduction order."""

    trainer: Trainer
    seeds: tuple[int, ...]
    init: Callable[[], RunnerState]
    run: Callable[[RunnerState, int], tuple[RunnerState, dict[str, jax.Array]]]


def make_seed_trainer(
    trainer: Trainer, seeds: tuple[int, ...], devices: int | None = None
) -> SeedTrainer:
    """Vmap `trainer` over `seeds`. The trainer must use one device for its envs (the
    devices go to the seeds instead). `devices`: None spreads the seeds over all devices
    when their number divides the seed count (else one device); n > 0 over the first n,
    which must divide it."""
    if trainer.env.mesh is not None:
        raise ValueError(
            "several seeds in one run spread the seeds over the devices, not the envs: "
            "build the trainer with devices=1"
        )
    seeds = tuple(int(s) for s in seeds)
    n_dev = jax.device_count() if devices is None else sharding.device_count(devices)
    if devices is not None and len(seeds) % n_dev:
        raise ValueError(f"{len(seeds)} seeds do not divide over {n_dev} devices")
    sharding_ = None
    if n_dev > 1 and len(seeds) % n_dev == 0:
        mesh = jax.sharding.Mesh(jax.devices()[:n_dev], ("seeds",))
        sharding_ = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("seeds"))

    def init_all() -> RunnerState:
        keys = jnp.stack([jax.random.key(s) for s in seeds])
        return init_each(trainer.init, keys)

    run_all = jax.vmap(trainer.run, in_axes=(0, None))
    if sharding_ is None:
        init, run = jax.jit(init_all), jax.jit(run_all)
    else:
        init = jax.jit(init_all, out_shardings=sharding_)
        run = jax.jit(run_all, in_shardings=(sharding_, None), out_shardings=sharding_)
    return SeedTrainer(trainer=trainer, seeds=seeds, init=init, run=run)


def init_each(init: Callable[[jax.Array], Any], keys: jax.Array) -> Any:
    """`init` of each key, stacked: vmapped, except on a CPU backend, where the members
    start one after another (`lax.map`). Vmapped, the networks' orthogonal initialisation
    is a batched LAPACK QR, which can deadlock XLA's CPU thread pool (envs/linalg.py)."""
    if jax.default_backend() == "cpu":
        return jax.lax.map(init, keys)
    return jax.vmap(init)(keys)


def take_seed(tree: Any, i: int) -> Any:
    """Seed i's slice of a seed-batched pytree (RunnerState or metrics)."""
    return jax.tree.map(lambda x: x[i], tree)


def stratified_minibatches(x: jax.Array, order: jax.Array, num_minibatches: int) -> jax.Array:
    """A (T, n, ...) batch of n environments cut into minibatches stratified by env.

    order: (T, n), column j a permutation of env j's time steps (a new one every epoch).
    After permuting, the rows are cut into gcd(M, T) blocks of consecutive rows and the
    envs into M / gcd(M, T) groups (env j in group j % groups); a minibatch is one block
    of one group. With M dividing T (the presets: one group) every minibatch holds T / M
    random steps of every env. Which samples share a minibatch depends only on global env
    indices (given that each device's share of envs is a multiple of the group count),
    so devices can cut their own envs' shards and together form the global minibatches.

    Returns (M, T * n / M, ...).
    """
    T, n = x.shape[:2]
    M = num_minibatches
    blocks = math.gcd(M, T)
    groups = M // blocks
    x = jnp.take_along_axis(x, order.reshape(order.shape + (1,) * (x.ndim - 2)), axis=0)
    x = x.reshape(blocks, T // blocks, n // groups, groups, *x.shape[2:])
    x = jnp.moveaxis(x, 3, 1)  # (blocks, groups, rows, envs of the group, ...)
    return x.reshape(M, (T // blocks) * (n // groups), *x.shape[4:])


def rollout_metrics(traj: Transition, done: jax.Array) -> dict[str, jax.Array]:
    """Means over the rollout's (T, N) steps. Env metrics are used where the env reports
    them: distance / position_error (m -> mm), orientation_error (rad -> deg), collided,
    nonfinite_actions."""
    m = traj.metrics
    episodes = jnp.sum(done)
    out = {
        "reward_mean": jnp.mean(traj.reward),
        "episodes": episodes.astype(jnp.float32),
        # Mean return of the episodes that ended in this rollout; NaN if none did.
        "episode_return": jnp.where(
            episodes > 0, jnp.sum(traj.episode_return) / jnp.maximum(episodes, 1), jnp.nan
        ),
        "terminations": jnp.sum(traj.terminated).astype(jnp.float32),
    }
    if "distance" in m:
        out["distance_mm"] = 1000.0 * jnp.mean(m["distance"])
    if "position_error" in m:
        out["position_error_mm"] = 1000.0 * jnp.mean(m["position_error"], axis=(0, 1))
    if "orientation_error" in m:
        out["orientation_error_deg"] = jnp.degrees(jnp.mean(m["orientation_error"], axis=(0, 1)))
    if "collided" in m:
        out["collision_rate"] = jnp.mean(m["collided"])
    if "nonfinite_actions" in m:
        out["nonfinite_actions"] = jnp.sum(m["nonfinite_actions"])
    return out


def probe_metric_summary(m: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """Accuracy of the deterministic policy: one step with the Gaussian mean from every
    env's state at the end of the rollout. `det_error_mm` is the mean over envs and axes of
    |e| after that step, the "mean per-axis error" of the time-to-accuracy records."""
    out = {}
    if "position_error" in m:
        per_axis = 1000.0 * jnp.mean(m["position_error"], axis=0)
        out["det_position_error_mm"] = per_axis
        out["det_error_mm"] = jnp.mean(per_axis)
    if "distance" in m:
        out["det_distance_mm"] = 1000.0 * jnp.mean(m["distance"])
    if "orientation_error" in m:
        out["det_orientation_error_deg"] = jnp.degrees(jnp.mean(m["orientation_error"], axis=0))
    return out


def num_parameters(params: Any) -> int:
    return sum(math.prod(x.shape) for x in jax.tree.leaves(params))
