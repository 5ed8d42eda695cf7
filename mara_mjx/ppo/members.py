"""Several runs in one jitted program: the seeds of `--seeds` and the members of a
population (CurriculumConfig.population), each a leading axis of the RunnerState.

    init, run = population(init, run, config)     # one member's -> K members' + exploit
    seeds = make_seed_trainer(trainer, (0, 1, 2))  # a Trainer vmapped over seeds
    state = seeds.init(); state, metrics = seeds.run(state, n); take_seed(state, 1)

`mara_mjx.ppo.train.make_train` applies `population` when the config asks for one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from mara_mjx.runtime import sharding

RunnerState = Any  # mara_mjx.ppo.train.RunnerState (not imported: train imports this module)


def population(
    init: Callable[[jax.Array], RunnerState],
    run: Callable[[RunnerState, jax.Array], tuple[RunnerState, dict[str, jax.Array]]],
    config: Any,
):
    """`init` and `run` of one member turned into those of `config.curriculum.population`
    members (vmapped) with population-based training's exploit step (a TrainConfig:
    CurriculumConfig.population, exploit_every, exploit_fraction; PPOConfig's updates).

    Member 0 starts from the run's key itself (so its start is a single run's), member k
    from fold_in(key, k). Exploit, at the end of a `run` call that crossed a multiple of
    the exploit interval (exploit_every of the updates) or reached the last update:
    members ranked by fitness (their summed mean training reward per step since the last
    exploit); slot i takes the i-th best for i < K - n, the n = max(1, floor(K *
    exploit_fraction)) remaining slots take copies of the n best; PRNG keys stay with
    their slots. So the exploit points fall on call boundaries (RunConfig.updates_per_call)
    and a run is reproducible for a given updates_per_call. The metrics are member 0's.

    The members are vmapped around the whole scanned `run`, as --seeds vmaps seeds."""
    K, total_updates = config.curriculum.population, config.ppo.num_updates
    n_copy = min(K - 1, max(1, int(K * config.curriculum.exploit_fraction)))
    interval = max(1, round(config.curriculum.exploit_every * total_updates))

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
            (after // interval > before // interval) | (after == total_updates)
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

    trainer: Any  # mara_mjx.ppo.train.Trainer
    seeds: tuple[int, ...]
    init: Callable[[], RunnerState]
    run: Callable[[RunnerState, int], tuple[RunnerState, dict[str, jax.Array]]]


def make_seed_trainer(
    trainer: Any, seeds: tuple[int, ...], devices: int | None = None
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
