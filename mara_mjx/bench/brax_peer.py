"""brax's PPO as the peer of ours in the `brax` study (`mara_mjx.bench.ppo`).

`brax_kwargs` maps our `PPOConfig` onto the arguments of brax's
`brax.training.agents.ppo.train.train` as closely as brax allows (`unmatched` lists our
values brax has no equivalent for); `train_brax` runs brax's PPO on
`mara_mjx.adapters.brax_env.make_brax_env(task)` with a policy snapshot per training
epoch on the same `CompileClock` and in the same `Run` as ours
(`mara_mjx.bench.ppo_runs`), and returns the deterministic brax policy mapped onto joint
targets, for the common scorer.

brax 0.14.2 calls `jax.device_put_replicated`, which JAX 0.10 removed; importing
`mara_mjx.adapters.brax_env` provides JAX's documented drop-in replacement (and imports
mujoco.mjx quietly, before brax does), so this module imports it before brax.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from tqdm import tqdm

from mara_mjx.bench.ppo_runs import CompileClock, Run
from mara_mjx.ppo import PPOConfig


def brax_kwargs(config: PPOConfig, episode_length: int) -> dict[str, Any]:
    """brax `ppo.train` arguments matching `config` as closely as brax allows.

    Matched: envs, unroll length (= num_steps), minibatches and their size (brax's
    `batch_size` counts unrolls: num_envs / num_minibatches of num_steps steps = our
    minibatch), epochs, learning rate, discount, GAE lambda, policy clip, value clip
    (`clipping_epsilon_value` = clip_eps when clip_value), value coefficient, entropy
    cost (0 in the default preset: no entropy bonus on either side), gradient-norm clip,
    advantage normalisation, observation normalisation, reward scaling, separate tanh
    MLPs of `hidden_sizes` for policy and value, state-independent noise, seed, horizon.
    Not matchable (brax's own; `unmatched` lists our values): a constant learning rate
    (ours: `lr_schedule`, linear to 0 in the default preset), Adam eps 1e-8 (ours 1e-5),
    absolute actions, a tanh-squashed Gaussian in [-1, 1] mapped to the joint box by the
    adapter (ours: a Gaussian on joint targets in rad, in the default preset relative to
    the current joint positions, `relative_actions`), brax's noise parametrisation
    (softplus scale, init 1, floor 0.001) and lecun-uniform initialisation (ours: a
    log-std with `init_log_std` and `log_std_floor`, orthogonal), no clipping of
    normalised observations (ours: +-`obs_clip`), and truncation handled by masking in
    GAE (ours: bootstrap from the final obs)."""
    import flax.linen as nn

    import mara_mjx.adapters.brax_env  # noqa: F401  (before brax: quiet mujoco.mjx, JAX shim)

    # isort: split
    from brax.training.agents.ppo import networks as ppo_networks

    if config.num_envs % config.num_minibatches:
        raise ValueError(
            f"brax needs num_envs ({config.num_envs}) divisible by num_minibatches "
            f"({config.num_minibatches}): its minibatch is a whole number of unrolls"
        )
    factory = functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=tuple(config.hidden_sizes),
        value_hidden_layer_sizes=tuple(config.hidden_sizes),
        activation=nn.tanh,
    )
    return {
        "num_envs": config.num_envs,
        "episode_length": episode_length,
        "unroll_length": config.num_steps,
        "batch_size": config.num_envs // config.num_minibatches,
        "num_minibatches": config.num_minibatches,
        "num_updates_per_batch": config.update_epochs,
        "learning_rate": config.learning_rate,
        "discounting": config.gamma,
        "gae_lambda": config.gae_lambda,
        "clipping_epsilon": config.clip_eps,
        "clipping_epsilon_value": config.clip_eps if config.clip_value else None,
        "vf_loss_coefficient": config.vf_coef,
        "entropy_cost": config.ent_coef,
        "max_grad_norm": config.max_grad_norm,
        "normalize_advantage": config.normalize_advantages,
        "normalize_observations": config.normalize_obs,
        "reward_scaling": config.reward_scale,
        "network_factory": factory,
        "seed": config.seed,
    }


def unmatched(config: PPOConfig) -> dict[str, Any]:
    """Our values of the PPOConfig fields brax has no equivalent for (see brax_kwargs)."""
    names = ("lr_schedule", "adam_eps", "relative_actions", "init_log_std", "log_std_floor")
    names += ("obs_clip",)
    d = config.flat()  # a TrainConfig: every section's fields
    return {name: d[name] for name in names if name in d}


def train_brax(
    task: str,
    config: PPOConfig,
    updates_per_call: int,
    episode_length: int,
    progress: bool = True,
) -> tuple[Run, Callable[[Any, jax.Array], jax.Array]]:
    """brax's PPO on `make_brax_env(task)`, `config.num_updates` updates of the same
    batch as ours, one epoch (= snapshot) per `updates_per_call` updates. Returns the run
    and act(params, obs) -> joint targets (the deterministic brax policy, mapped)."""
    from mara_mjx.adapters.brax_env import make_brax_env  # before brax: see the module docstring

    # isort: split
    from brax.training.agents.ppo import train as brax_ppo

    if config.num_updates % updates_per_call:
        raise ValueError(
            f"brax: {config.num_updates} updates are not a multiple of updates_per_call="
            f"{updates_per_call}; choose --total so that both sides do the same env steps"
        )
    benv = make_brax_env(task, episode_length=episode_length)
    calls = config.num_updates // updates_per_call
    total = config.num_updates * config.batch_size
    holder: dict[str, Any] = {}
    bar = tqdm(
        total=total,
        unit="step",
        unit_scale=True,
        desc=f"brax {task}",
        disable=not progress,
        file=sys.stderr,
    )

    with CompileClock() as clock:
        run = Run("brax ppo", task)
        brax_metrics: list[dict[str, float]] = []

        def policy_params_fn(step: int, make_policy: Any, params: Any) -> None:
            holder["make_policy"] = make_policy
            run.add(clock, int(step), jax.device_get(params))
            bar.update(int(step) - bar.n)

        def progress_fn(step: int, metrics: dict[str, Any]) -> None:
            brax_metrics.append(
                {k: float(v) for k, v in metrics.items() if k.startswith("training/")}
            )

        brax_ppo.train(
            environment=benv,
            num_timesteps=total,
            num_evals=calls + 1,
            run_evals=False,
            progress_fn=progress_fn,
            policy_params_fn=policy_params_fn,
            **brax_kwargs(config, episode_length),
        )
        run.wall_s = clock.read()[0]
    bar.close()
    sps = [m["training/sps"] for m in brax_metrics[1:] if "training/sps" in m]
    run.extra["brax_reported_sps_median"] = float(np.median(sps)) if sps else None
    if run.curve[-1]["env_steps"] != total:
        raise RuntimeError(f"brax ran {run.curve[-1]['env_steps']} env steps, ours {total}")
    make_brax_policy = holder["make_policy"]
    key = jax.random.PRNGKey(0)  # unused by the deterministic policy

    def act(params: Any, obs: jax.Array) -> jax.Array:
        action, _ = make_brax_policy(params, deterministic=True)(obs, key)
        return benv.to_joint_targets(action)

    return run, act
