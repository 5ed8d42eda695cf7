"""Imitation of a trained policy (`CurriculumConfig.teacher`): a student network that acts
alone learns to do what a teacher's deployed policy does.

The teacher is any policy a run of the same task saved, deployed rules included (the IK
residual and its gates, the orient-first rule, the IK finish, the collision guard), but
for the plan and its restarts (PolicyConfig.plan_steps, plan_starts): the teacher acts
one step at a time, as its network was trained (a plan costs 16 or more of its calls per
label; benchmarks/NOTES.md section 60). The
student trains on the states its own sampled policy visits (DAgger without a mixing
schedule: the teacher is asked at every visited state and never acts), and its loss is
the negative log-likelihood of the teacher's action (clipped to the joint box, what the
env would execute; near the target, with CurriculumConfig.imitation_lookahead, the
teacher's action a few steps ahead: `lookahead_action`) under the student's Gaussian:
the mean learns the teacher's action and the standard deviation the size of its own
error, so the rollouts' noise shrinks with it (down to `PPOConfig.log_std_floor`). No
reward is maximised; the value head is not trained. The student is a plain network
(`default`'s parametrisation), exportable to `.npz` or ONNX without any IK in its graph:
the way to "the learnt policy alone" at the teacher's accuracy (benchmarks/NOTES.md
section 51).

    teacher = load_teacher("runs/MARAOrient-.../seed_1000", "MARAOrient")
    trainer = make_train(env, PRESETS["distill"].replace(teacher="runs/..."), teacher=teacher)

With `--seeds`, a teacher run of several seeds (`<run>/seed_<s>/`) gives student seed s
the teacher of seed s (`teachers_for_seeds`); a single run or checkpoint teaches them all.
A single student run (no `--seeds`) learns from the teacher run's seed of its own seed.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from mara_mjx.ppo.checkpoint import CheckpointError, find_checkpoint, load_checkpoint
from mara_mjx.ppo.policy import Policy, policy_from_checkpoint


def _load(path: Path, env_name: str) -> Policy:
    arrays, meta = load_checkpoint(find_checkpoint(path))
    if meta["env_name"] != env_name:
        raise ValueError(
            f"teacher {str(path)!r} was trained on {meta['env_name']}, not {env_name}: a "
            "teacher must be a run of the task the student trains on"
        )
    policy = policy_from_checkpoint(arrays, meta).one_step()  # its step, not its plan
    # its training seed does not act in the deterministic policy; one value keeps the
    # state's structure the same whichever seed's teacher it holds
    return policy.replace(config=policy.config.replace(seed=0))


def load_teacher(path: str | Path, env_name: str, seed: int | None = None) -> Policy:
    """The deployed `Policy` of a teacher run folder (its newest checkpoint) or checkpoint
    file. Of a run of several seeds (`seed_<s>/` folders): `seed_<seed>`, the student's own
    seed (a ValueError naming the seeds it holds where it has none such), or with seed None
    the first seed's (the template of a --seeds program, whose teachers_for_seeds pairs
    every seed). ValueError naming the problem."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"teacher {str(path)!r} does not exist: give a run folder or checkpoint")
    seeds = sorted(path.glob("seed_*")) if path.is_dir() else []
    if seeds and seed is not None:
        if not (path / f"seed_{seed}").is_dir():
            have = [p.name[5:] for p in seeds]
            raise ValueError(
                f"teacher {str(path)!r} is a run of seeds {', '.join(have)} and has no "
                f"seed_{seed} for this student's seed {seed}: give one seed's folder "
                f"(--teacher {path / seeds[0].name}), or train the student with --seed and "
                "--seeds matching the teacher's, which pairs seed s with seed_s"
            )
        seeds = [path / f"seed_{seed}"]
    try:
        return _load(seeds[0] if seeds else path, env_name)
    except CheckpointError as e:
        raise ValueError(f"teacher: {e}") from e


def teachers_for_seeds(path: str | Path, env_name: str, seeds: tuple[int, ...]) -> Policy:
    """One teacher per student seed, stacked on a leading seed axis (the --seeds program's
    RunnerState.teacher): `<path>/seed_<s>` for seed s where `path` holds seed folders
    (every seed's must exist), else the one teacher of `path` for every seed."""
    path = Path(path)
    if path.is_dir() and any(path.glob("seed_*")):
        missing = [s for s in seeds if not (path / f"seed_{s}").is_dir()]
        if missing:
            have = sorted(int(p.name[5:]) for p in path.glob("seed_*") if p.name[5:].isdigit())
            raise ValueError(
                f"teacher {str(path)!r} has no seed folder for student seed(s) {missing} "
                f"(it has seeds {have}); train the teacher with the same --seed and --seeds"
            )
        try:
            policies = [_load(path / f"seed_{s}", env_name) for s in seeds]
        except CheckpointError as e:
            raise ValueError(f"teacher: {e}") from e
    else:
        policies = [load_teacher(path, env_name)] * len(seeds)
    if len({p.config for p in policies}) > 1:
        raise ValueError(
            f"the teacher's seeds in {str(path)!r} were trained with different configs"
        )
    return jax.tree.map(lambda *x: jnp.stack(x), *policies)


def imitation_loss(mean: jax.Array, log_std: jax.Array, target: jax.Array) -> jax.Array:
    """Mean over the batch of the Gaussian negative log-likelihood of `target` (the
    teacher's action), constants dropped: sum over joints of 0.5 ((t - mu) / sigma)^2 +
    log sigma."""
    z = (target - mean) * jnp.exp(-log_std)
    return jnp.mean(jnp.sum(0.5 * jnp.square(z) + log_std, axis=-1))


def teacher_action(teacher: Policy, obs: jax.Array, lower: Any, upper: Any) -> jax.Array:
    """The teacher's deployed action for raw observations, clipped to the joint box."""
    return jnp.clip(teacher(obs), lower, upper)


def imitation_labeller(
    step: Any, lower: Any, upper: Any, curriculum: Any
) -> Callable[[Policy, Any], jax.Array]:
    """(teacher, state) -> the imitation labels of a batch of states, as `curriculum`
    (CurriculumConfig) asks: `lookahead_action` with its imitation_lookahead steps within
    imitation_lookahead_mm (1 step: the teacher's own action, `teacher_action`)."""
    steps, radius = curriculum.imitation_lookahead, curriculum.imitation_lookahead_mm / 1000.0
    return lambda teacher, state: lookahead_action(
        teacher, step, state, lower, upper, steps, radius
    )


def lookahead_action(
    teacher: Policy,
    step: Any,
    state: Any,
    lower: Any,
    upper: Any,
    steps: int,
    radius: float,
) -> jax.Array:
    """The imitation label with CurriculumConfig.imitation_lookahead: the teacher's action
    k steps ahead, a_k = teacher(s_k) with s_{j+1} = step(s_j, a_j) from s_0 = `state`
    (a batch: `.obs` (N, obs_size), its position error in obs[:, 6:9] (m), and after a
    step `.terminated`, `.truncated` and `.metrics["collided"]`), for the largest
    k < `steps` such that s_0 .. s_k all have |e| < `radius` (m) and no step on the way
    ended its episode or collided (the env then puts the arm back at the reset pose); a_0,
    the teacher's own action, where s_0 is outside. `step` is the env's pure step, so
    the real rollout is not moved. The joints the teacher arrives at rather than the ones
    it passes: continuous where the teacher's last approach stops and jumps. One copy of
    the teacher and the step in the program (a fori_loop), whatever `steps`."""
    action = teacher_action(teacher, state.obs, lower, upper)
    if steps <= 1:
        return action

    def near(obs):
        return jnp.sum(jnp.square(obs[..., 6:9]), axis=-1) < radius**2

    def ahead(_, carry):
        state, action, label, ok = carry
        state = step(state, action)
        ended = state.terminated | state.truncated | (state.metrics["collided"] > 0)
        ok = ok & near(state.obs) & ~ended
        action = teacher_action(teacher, state.obs, lower, upper)
        return state, action, jnp.where(ok[..., None], action, label), ok

    carry = (state, action, action, near(state.obs))
    return jax.lax.fori_loop(0, steps - 1, ahead, carry)[2]


def rollout_sigma(log_std: jax.Array, spread: float) -> jax.Array:
    """The imitation rollouts' noise (CurriculumConfig.imitation_spread): per env i of the
    N rows of `log_std` (N, A), max(exp(log_std), spread * i / (N - 1)): env 0 samples with
    the student's own sigma, env N - 1 at least `spread` rad, a continuum between (the
    last millimetres of the teacher's path and the states well off it, both visited; a
    single wide floor loses the first: benchmarks/NOTES.md section 54)."""
    sigma = jnp.exp(log_std)
    if spread <= 0.0:
        return sigma
    n = log_std.shape[0]
    ramp = jnp.arange(n, dtype=sigma.dtype) / max(n - 1, 1)
    return jnp.maximum(sigma, spread * ramp[:, None])
