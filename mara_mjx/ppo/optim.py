"""The SGD's pieces of a PPO update: the learning-rate schedule, the optimiser, and the
cut of a rollout's (T, N) batch into minibatches stratified by environment (so that, over
several devices, each device's minibatches are its own envs' share of the global ones)."""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax

from mara_mjx.ppo.config import PPOConfig


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
