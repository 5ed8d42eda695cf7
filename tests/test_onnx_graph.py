"""The .onnx export of a policy with IK rules (mara_mjx/deploy/onnx_graph.py, traced by
jax2onnx): onnxruntime against the JAX policy to 1e-4 inside, outside and across every zone
boundary of orient-first's rules (1e-3 relative off each threshold: exactly on one, a
float32 ulp may flip the rule in either runtime), the robot-side runner on the file, and a
corrupted graph refused by the self-check. One export (static batch 1, the robot's), CPU."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_export_plots import make_run

import mara_mjx.envs.task_space as ts
from mara_mjx.cli.export import export_policy
from mara_mjx.ppo import make_policy

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("jax2onnx")
from mara_mjx.deploy import onnx_graph  # noqa: E402

ORIENT_FIRST = {
    "ik_prior": "residual",
    "ik_gate": 0.1,
    "ik_wrap": True,
    "ik_gate_wrap": True,
    "ik_orient_first": True,
    "collision_guard_mm": 5.0,
}
"""PRESETS["orient_first"]'s deployed rules but its plan and restarts (test_plan.py exports
those; here they would cost minutes), its training-only ones not being exported."""
SIDES = (1.0 - 1e-3, 1.0 + 1e-3)  # inside and outside each threshold
ROWS = 144  # every JAX evaluation here is padded to this batch: one compile


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("orient_first")
    run = make_run(folder / "run", "MARAOrient", True, relative=True, **ORIENT_FIRST)
    out = export_policy(folder / "run", folder / "policy.onnx", batch=1)
    model = onnx.load(str(out))
    meta = json.loads({p.key: p.value for p in model.metadata_props}["mara_mjx"])
    policy = make_policy(run)
    step = onnx_graph.deployed_step(policy, meta["action"]["lower"], meta["action"]["upper"])
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    jitted = jax.jit(step)

    def jax_step(obs):  # (n <= ROWS, 16) -> (action, action_clipped) (n, 6), one compile
        padded = np.concatenate([obs, np.repeat(obs[:1], ROWS - len(obs), 0)])
        return [np.asarray(x)[: len(obs)] for x in jitted(jnp.asarray(padded, jnp.float32))]

    def spread(obs):  # (n <= ROWS,) the step's own spread under input rounding (own_spread)
        padded = np.concatenate([obs, np.repeat(obs[:1], ROWS - len(obs), 0)])
        want = [np.asarray(x) for x in jitted(jnp.asarray(padded, jnp.float32))]
        return onnx_graph.own_spread(step, padded, want)[: len(obs)]

    jax_step.spread = spread
    return out, model, meta, jax_step, session


def _unit(rng, n, d):
    x = rng.normal(size=(n, d))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _turn(axes, angle):  # (n, 3), (n,) -> (n, 4) (w, x, y, z)
    return np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axes], 1)


def zone_families(meta, n=12):
    """name -> (inside, outside) observations (n, 16) at each of orient-first's thresholds."""
    rng = np.random.default_rng(3)
    q = onnx_graph.check_observations(meta, n)[:, :6]  # well-conditioned arm poses
    v = rng.normal(0.0, 0.1, (n, 3))
    dirs, axes = _unit(rng, n, 3), _unit(rng, n, 3)

    def obs(e, quat):
        return np.concatenate([q, e, quat, v], 1).astype(np.float32)

    angle = rng.uniform(0.03, 0.7, n)  # standoff: 0.5 x the angle left after a step, >= 1 cm
    floor = ts.ORIENT_FIRST_STANDOFF * np.maximum(angle - ts.MAX_ROTATION_STEP, 0)
    floor = np.maximum(floor, ts.ORIENT_FIRST_HOLD)
    near_angle = rng.uniform(0.0, 0.5, n)
    close = rng.uniform(0.005, 0.1, (n, 1))
    families = {
        "aligned (angle 0.02 rad)": lambda s: obs(
            dirs * close, _turn(axes, np.full(n, ts.ORIENT_FIRST_ALIGNED * s))
        ),
        "near and guard (|e| 6 cm)": lambda s: obs(
            dirs * ts.ORIENT_FIRST_NEAR * s, _turn(axes, near_angle)
        ),
        "standoff": lambda s: obs(dirs * (floor * s)[:, None], _turn(axes, angle)),
        "position step cap": lambda s: obs(
            dirs * ((floor + ts.MAX_POSITION_STEP) * s)[:, None], _turn(axes, angle)
        ),
        "rotation step cap (0.25 rad)": lambda s: obs(
            dirs * 0.03, _turn(axes, np.full(n, ts.MAX_ROTATION_STEP * s))
        ),
        "gate scale (|e| 0.1 m)": lambda s: obs(dirs * 0.1 * s, _turn(axes, near_angle)),
    }
    return {name: tuple(build(s) for s in SIDES) for name, build in families.items()}


def _run(session, obs):  # the file's static batch of 1
    return np.concatenate([session.run(["action_clipped"], {"obs": o[None]})[0] for o in obs])


def test_the_graph_matches_the_jax_policy_across_orient_first_zones(exported):
    out, model, meta, step, session = exported
    # 1e-4 plus the jit's own spread under input rounding (a few 1e-4 at a few of the 128
    # check observations on some CPUs): far below a wrong graph's differences
    check = meta["self_check"]
    assert meta["rules_in_graph"] and check["max_abs_diff"] <= 2e-3, check
    assert "own spread" in check["reference"], check
    assert meta["recipe"]["config"]["policy"]["ik_orient_first"] and meta["control_dt"] == 0.05
    assert "ik_finish" not in meta  # the runner's numpy finish does not run on top
    assert model.graph.input[0].type.tensor_type.shape.dim[0].dim_value == 1
    families = zone_families(meta)
    obs = np.concatenate([o for sides in families.values() for o in sides])
    got, want = _run(session, obs), step(obs)[1]
    assert np.abs(want - obs[:, :6]).max() > 0.05  # the policy moves the arm
    rows = np.abs(got - want).max(1)
    err = rows.reshape(len(families), 2, -1).max(2)
    # 1e-4, plus the jit's own spread where 2-4 ulps of input rounding move it more (as the
    # exporter's check): one float32 evaluation cannot be held closer to another there
    allowed = 1e-4 + onnx_graph.SPREAD_MARGIN * step.spread(obs)
    assert (rows <= allowed).all(), dict(zip(families, err.tolist(), strict=True))
    assert np.mean(rows <= 1e-4) >= 0.95, dict(zip(families, err.tolist(), strict=True))
    # across the near zone the guard and the gates switch: the two sides' steps differ
    near = list(families).index("near and guard (|e| 6 cm)")
    sides = want.reshape(len(families), 2, -1, 6)[near]
    assert np.abs(sides[0] - sides[1]).max() > 1e-2


def test_the_runner_runs_the_graph(exported):
    """PolicyRunner on the file: the JAX policy's clipped step of the runner's observation."""
    from mara_mjx.deploy.runner import PolicyRunner

    out, _, meta, step, _ = exported
    runner = PolicyRunner.load(out)
    chain = ts.nominal_chain()
    q = onnx_graph.check_observations(meta, 4, seed=1)[:, :6]
    targets = jnp.asarray(q + np.random.default_rng(5).normal(0.0, 0.2, q.shape), jnp.float32)
    target_pos, target_quat = (np.asarray(x) for x in jax.vmap(chain.tcp)(targets))
    obs, got = [], []
    for i in range(len(q)):
        runner.reset()
        obs.append(runner.observe(q[i], target_pos[i], target_quat[i]))
        got.append(runner.step(q[i], target_pos[i], target_quat[i]))
    np.testing.assert_allclose(got, step(np.array(obs))[1], atol=1e-4, rtol=0)
    # a batch of arms through the one-arm file (evaluate's loop runs 10 episodes at once):
    # the rows in turn, as the file's own one-row calls give them
    rows = np.array(obs)
    np.testing.assert_array_equal(
        runner.act(rows), np.concatenate([runner.act(r[None]) for r in rows])
    )


def test_a_corrupted_graph_fails_the_self_check(exported):
    out, model, meta, step, _ = exported
    bad = onnx.ModelProto()
    bad.CopyFrom(model)
    weights = [t for t in bad.graph.initializer if len(t.dims) == 2 and min(t.dims) > 1]
    assert weights  # the actor's kernels
    array = onnx.numpy_helper.to_array(weights[0]) + np.float32(1e-2)
    weights[0].CopyFrom(onnx.numpy_helper.from_array(array, weights[0].name))
    obs = onnx_graph.check_observations(meta, 16)
    want = step(obs)
    assert onnx_graph.self_check(model, obs, want, 1) <= 1e-4
    with pytest.raises(onnx_graph.OnnxGraphError, match="differs from the JAX policy"):
        onnx_graph.self_check(bad, obs, want, 1)


def test_a_planned_policy_is_held_to_the_jits_own_spread(exported):
    """A plan's check (build_model with plan_steps): each observation within the bound
    plus what an ulp of input rounding moves the jitted step by (own_spread), and only
    there: a smooth step has no spread, a chaotic one does."""
    _, model, meta, step, _ = exported
    obs = onnx_graph.check_observations(meta, 16)
    smooth = lambda o: (jnp.sin(o[..., :6]), jnp.sin(o[..., :6]))  # noqa: E731
    chaotic = lambda o: (jnp.sin(1e8 * o[..., :6]), jnp.sin(o[..., :6]))  # noqa: E731
    for f, low, high in ((smooth, 0.0, 1e-6), (chaotic, 0.1, 2.0)):
        spread = onnx_graph.own_spread(f, obs, [np.asarray(x) for x in jax.jit(f)(obs)], 4)
        assert spread.shape == (16,) and low <= spread.min() and spread.max() <= high
    want = step(obs)
    off = [w.copy() for w in want]
    off[0][3] += 2e-3  # one observation 2e-3 rad off: allowed only where its spread is
    allowed = np.full(16, 1e-4)
    with pytest.raises(
        onnx_graph.OnnxGraphError,
        match="1 beyond their tolerance, the worst by 2.0.e-03 where 1.00e-04 is allowed",
    ):
        onnx_graph.self_check(model, obs, off, 1, allowed)
    allowed[3] = 1e-4 + 3e-3
    assert 1.9e-3 < onnx_graph.self_check(model, obs, off, 1, allowed) < 2.1e-3
    off[0][5] = np.nan  # a non-finite reference is never within any allowance
    with pytest.raises(onnx_graph.OnnxGraphError, match="1 beyond their tolerance"):
        onnx_graph.self_check(model, obs, off, 1, allowed + 1.0)
