"""PolicyConfig.plan_steps (mara_mjx.ppo.policy.planned_landing): the deployed policy
commands the landing of K imagined train-driver steps on the nominal arm. Checked against
the env itself: K steps of the train driver from the same observation land where the plan
says (where no step collides), on a task with and without an orientation; the options'
bad values refused; the evaluation's override; the ONNX trace of a planned policy (with
one of PolicyConfig.plan_starts' restarts, whose graph holds the own plan)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_export_plots import make_run

import mara_mjx
from mara_mjx.ppo import PolicyConfig, make_policy
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import with_deployed

K = 3
IK = {"ik_prior": "residual", "ik_gate": 0.1}  # the IK step moves the arm toward the target


@pytest.mark.parametrize("env_name", ["MARAOrient", "MARACollision"])
def test_the_plan_lands_where_k_train_driver_steps_land(env_name):
    from mara_mjx.ppo.policy import planned_landing

    env = mara_mjx.make(env_name)
    w = jax.random.normal(jax.random.key(1), (env.observation_size, 6))

    def act(obs):  # small steps that depend on every part of the observation (e, quat, v)
        return obs[..., :6] + 0.08 * jnp.tanh(4.0 * obs @ w)

    params = env.make_params(reset_noise=0.3)
    state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(4), 32), params)
    obs0 = state.obs
    step = jax.jit(jax.vmap(env.step))
    for _ in range(K):
        state = step(state, act(state.obs))
    clean = np.asarray(state.metrics["collisions"]) == 0
    assert clean.sum() >= 16, "too few episodes without a collision to compare"
    landing = np.asarray(jax.jit(lambda o: planned_landing(act, o, K))(obs0))
    np.testing.assert_allclose(landing[clean], np.asarray(state.obs[:, :6])[clean], atol=1e-4)
    first = np.asarray(act(obs0))
    assert np.abs(landing - first)[clean].max() > 1e-2  # the plan is not the first step
    # one observation gives its row of the batch
    one = np.asarray(planned_landing(act, obs0[3], K))
    np.testing.assert_allclose(one, landing[3], atol=1e-5)


def test_a_policy_with_plan_steps_commands_its_plan(tmp_path):
    from mara_mjx.ppo.policy import planned_landing

    run = make_run(tmp_path / "run", "MARAOrient", True, relative=True, **IK)
    policy = make_policy(run)
    planned = with_deployed(policy, "plan_steps", K)
    obs = jax.vmap(mara_mjx.make("MARAOrient").reset)(jax.random.split(jax.random.key(0), 4)).obs
    np.testing.assert_allclose(
        np.asarray(planned(obs)), np.asarray(planned_landing(policy, obs, K)), atol=1e-6
    )
    assert with_deployed(planned, "plan_steps", 0).config.policy.plan_steps == 0


def test_bad_plan_steps_are_refused_with_the_valid_range():
    for bad in (-1, 65, 2.5):
        with pytest.raises(ValueError, match=r"plan_steps must be an int in \[0, 64\]"):
            PolicyConfig(plan_steps=bad)
    for bad in (-2, 65):
        with pytest.raises(ValueError, match=r"plan_steps must be -1 \(as trained\) or in"):
            EvalConfig(plan_steps=bad)
    from mara_mjx.ppo.parametrisation import resolve

    env = mara_mjx.make("MARA", control_dt=0.1)
    with pytest.raises(ValueError, match="default control period"):
        resolve(PolicyConfig(plan_steps=4, relative_actions=True), env)
    with pytest.raises(ValueError, match="has no config"):
        with_deployed(lambda obs: obs, "plan_steps", 4)


def test_a_plan_is_refused_at_another_control_period(tmp_path, monkeypatch):
    """Turned on after training (evaluate's override, export's flag), the plan is checked
    against the env it runs in: its imagined steps assume the default control period."""
    from mara_mjx.cli.export import ExportError, export_policy
    from mara_mjx.ppo.evaluation import make_evaluate

    run = make_run(tmp_path / "run", "MARA", False, relative=True)
    policy = make_policy(run)
    slow = mara_mjx.make("MARA", control_dt=0.1)
    fn = make_evaluate(slow, EvalConfig(episodes=2, plan_steps=3))
    with pytest.raises(ValueError, match="default control period"):
        fn(policy)
    # export of a run whose env runs at 0.1 s (its saved env config, patched here)
    from mara_mjx.runtime import runs

    saved = runs.env_overrides
    monkeypatch.setattr(runs, "env_overrides", lambda c: {**saved(c), "control_dt": 0.1})
    with pytest.raises(ExportError, match="default control period"):
        export_policy(run, tmp_path / "p.onnx", plan_steps=3)
    assert not (tmp_path / "p.onnx").exists()


def test_plan_steps_exports_to_onnx_and_matches(tmp_path, capsys):
    pytest.importorskip("jax2onnx")
    ort = pytest.importorskip("onnxruntime")
    from mara_mjx.cli.export import ExportError, export_policy
    from mara_mjx.deploy import onnx_graph

    # the actor's output constant (its bias): a smooth plan of IK steps; a random MLP's
    # iterated map amplifies float32 rounding beyond any fixed tolerance
    run = make_run(tmp_path / "run", "MARAOrient", True, relative=True, plan_steps=K,
                   constant_actor=True, **IK)  # fmt: skip
    # with one restart (PolicyConfig.plan_starts): its graph holds the own plan too
    out = export_policy(run, tmp_path / "policy.onnx", plan_starts=1)  # self-checked vs JAX
    # a planned graph without held commands: the note on servos (every call imagines)
    assert "--commit_rad 0.01" in capsys.readouterr().err
    with pytest.raises(ExportError, match="plan_steps"):
        export_policy(run, tmp_path / "policy.npz")
    policy = with_deployed(make_policy(run), plan_starts=1)
    assert policy.config.policy.plan_steps == K
    import json

    import onnx

    model = onnx.load(str(out))
    meta = json.loads({p.key: p.value for p in model.metadata_props}["mara_mjx"])
    # the restarts in a while loop over groups of the rows that miss (none: no iteration),
    # each group with its own imagined plan inside
    loops = [n for n in model.graph.node if n.op_type == "Loop"]
    bodies = [a.g for n in loops for a in n.attribute if a.name == "body"]
    assert any(any(m.op_type == "Loop" for m in body.node) for body in bodies)
    assert "own spread" in meta["self_check"]["reference"]  # the planned policy's rule
    obs = onnx_graph.check_observations(meta, 16)
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    (got,) = session.run(["action"], {"obs": obs})
    want = np.asarray(jax.jit(lambda p, o: p(o))(policy, jnp.asarray(obs)))
    np.testing.assert_allclose(got, want, atol=1e-4 * (1 + 32 / 4))  # (a restart: 32 steps)
    assert meta["recipe"]["config"]["policy"]["plan_starts"] == 1  # in the metadata
    unplanned = np.asarray(with_deployed(policy, plan_steps=0, plan_starts=0)(jnp.asarray(obs)))
    assert np.abs(got - unplanned).max() > 1e-3
