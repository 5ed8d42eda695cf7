"""The robot-side runner (mara_mjx/deploy/runner.py) against the env and the JAX policy:
its observation is the env's for the same joints and target, its joint targets are the
JAX policy's on the env's observation, and a closed-loop episode driven by it is the one
the JAX policy drives. Exports come from untrained checkpoints (test_export_plots.make_run).
"""

from __future__ import annotations

import functools
import json
import shutil
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import jitted
from test_export_plots import make_run

from mara_mjx.cli.export import export_policy, load_exported
from mara_mjx.deploy import ik_numpy, numpy_policy, runner
from mara_mjx.deploy.runner import PolicyRunner, RunnerError
from mara_mjx.ppo import make_policy

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")


@pytest.fixture(scope="module")
def exports(tmp_path_factory) -> dict:
    """MARAOrient (normaliser, relative actions, sign-canonical quat_err, hidden v,
    max_joint_step) as .npz and .onnx, and MARA with an IK finish as .npz."""
    tmp = tmp_path_factory.mktemp("runner")
    # seed 6: a random actor whose 40 steps from the reset pose collide nowhere and leave
    # some joint steps short of max_joint_step (the observation steers them)
    orient = make_run(
        tmp / "orient", "MARAOrient", True, seed=6, relative=True, max_joint_step=0.05
    )
    finish = make_run(tmp / "finish", "MARA", True, relative=True, ik_finish=0.06)
    return {
        "orient": make_policy(orient),
        "orient.npz": export_policy(tmp / "orient", tmp / "orient.npz"),
        "orient.onnx": export_policy(tmp / "orient", tmp / "orient.onnx"),
        "finish": make_policy(finish),
        "finish.npz": export_policy(tmp / "finish", tmp / "finish.npz"),
    }


@functools.cache
def _vstep(name: str):
    """This file's own vmapped step (the shared `jitted(name).vstep` may already be traced
    for another batch size by another test file in the same worker)."""
    return jax.jit(jax.vmap(jitted(name).env.step))


def _env_obs(name: str, q0: np.ndarray, q1: np.ndarray, pos: np.ndarray, quat: np.ndarray):
    """The env's observations (N, obs_size) after stepping each arm from joints q0 to q1
    (train driver: q1 reached, qvel = (q1 - q0) / control_dt), target (pos, quat)."""
    env = jitted(name)
    n = len(q0)
    state = env.reset(jax.random.key(0))
    state = jax.tree.map(lambda x: jnp.broadcast_to(x, (n, *x.shape)), state)
    params = state.params.replace(
        target_pos=jnp.asarray(pos, jnp.float32), target_quat=jnp.asarray(quat, jnp.float32)
    )
    state = state.replace(q=jnp.asarray(q0, jnp.float32), params=params)
    out = _vstep(name)(state, jnp.asarray(q1, jnp.float32))
    obs = np.asarray(out.obs)
    return obs, obs[:, :6]  # q1 in float32 (a colliding arm's state.q is the reset pose)


def _configs(seed: int, n: int = 64, spread: float = 0.2):
    """Random joints q0 inside the limits, q1 within `spread` rad of them, targets with
    random orientations (unnormalised, as a user may pass them)."""
    rng = np.random.default_rng(seed)
    q0 = rng.uniform(-2.0, 2.0, (n, 6))
    q1 = np.clip(q0 + rng.uniform(-spread, spread, (n, 6)), -2.3, 2.3)
    pos = rng.uniform([-0.5, -0.25, 0.7], [-0.2, 0.25, 0.9], (n, 3))
    quat = rng.normal(size=(n, 4)) * rng.uniform(0.5, 2.0, (n, 1))
    return q0, q1, pos, quat


def _runner_obs(r: PolicyRunner, q0, q1, pos, quat) -> np.ndarray:
    r.reset()
    r.step(q0, pos, quat)
    return r.observe(q1, pos, quat)


@pytest.mark.parametrize("name", ["orient.npz", "finish.npz"])
def test_observation_equals_the_envs(exports, name):
    """Several random configurations and targets, batched: q, e, quat_err (Orient) and v
    as the env computes them, to float32 precision; qvel 0 right after reset."""
    r = PolicyRunner.load(exports[name])
    env_name = "MARAOrient" if "orient" in name else "MARA"
    q0, q1, pos, quat = _configs(1)
    want, q_env = _env_obs(env_name, q0, q1, pos, quat / np.linalg.norm(quat, axis=1)[:, None])
    got = _runner_obs(r, q0, q_env, pos, quat)  # the env's float32 joints
    assert got.shape == want.shape == (64, r.observation_size)
    v = r.layout["v"]
    assert np.abs(want[:, v]).max() > 0.5  # the velocity term is exercised
    np.testing.assert_allclose(got[:, : v.start], want[:, : v.start], atol=2e-6, rtol=0)
    np.testing.assert_allclose(got[:, v], want[:, v], atol=2e-5, rtol=1e-5)
    # one arm, unbatched, gives the same row; right after reset v is 0
    r.reset()
    r.step(q0[3], pos[3], quat[3])
    np.testing.assert_allclose(r.observe(q_env[3], pos[3], quat[3]), got[3], atol=1e-12)
    r.reset()
    assert np.all(r.observe(q0, pos, quat)[:, v] == 0.0)


def test_nominal_chain_is_the_models():
    """The chain the runner uses for exports without one is the package's MARA model."""
    meta = ik_numpy.finish_meta(0.05)["chain"]
    for field, value in runner.NOMINAL_CHAIN.items():
        np.testing.assert_allclose(value, meta[field], atol=1e-12, err_msg=field)


@pytest.mark.parametrize("name", ["orient.npz", "orient.onnx", "finish.npz"])
def test_joint_targets_equal_the_jax_policys(exports, name):
    """runner.step's joint targets = the JAX policy's actions on the env's observation,
    clipped to the joint limits; for the IK finish, with targets inside its 6 cm zone
    too; and the .npz route = load_exported's NumpyPolicy."""
    r = PolicyRunner.load(exports[name])
    env_name = "MARAOrient" if "orient" in name else "MARA"
    q0, q1, pos, quat = _configs(2)
    if env_name == "MARA":  # half the targets within 6 cm of the TCP: the finish acts
        rng = np.random.default_rng(3)
        limits = {"joint_lower": r.joint_lower, "joint_upper": r.joint_upper}
        fk = ik_numpy.NumpyFinish({"chain": runner.NOMINAL_CHAIN, **limits})
        pos[::2] = fk.tcp(q1[::2]) + rng.uniform(-0.03, 0.03, (32, 3))
    quat_unit = quat / np.linalg.norm(quat, axis=1)[:, None]
    obs, q_env = _env_obs(env_name, q0, q1, pos, quat_unit)
    policy = exports[name.split(".")[0]]
    want = np.clip(np.asarray(policy(jnp.asarray(obs))), r.joint_lower, r.joint_upper)
    r.reset()
    r.step(q0, pos, quat)
    got = r.step(q_env, pos, quat)
    assert got.dtype == np.float64 and got.shape == (64, 6)
    assert np.all((got >= r.joint_lower) & (got <= r.joint_upper))
    assert np.abs(got - q_env).max() > 0.02  # the policy moves the arm
    np.testing.assert_allclose(got, want, atol=1e-5, rtol=0)
    if name.endswith(".npz"):
        np.testing.assert_allclose(
            got, load_exported(exports[name])(obs, clip=True), atol=1e-5, rtol=0
        )


@pytest.mark.parametrize("name", ["orient.npz", "orient.onnx"])
def test_closed_loop_episode_equals_the_jax_policys(exports, name):
    """The env stepped with the runner's joint targets (the runner reading the env's
    joints) follows the trajectory the JAX policy drives, to the same final pose."""
    env = jitted("MARAOrient")
    policy = jax.jit(lambda obs: exports["orient"](obs))
    target_pos = np.asarray(env.env.default_params.target_pos)
    r = PolicyRunner.load(exports[name])
    jax_state = run_state = env.reset(jax.random.key(0))
    r.reset()
    steps = []
    for _ in range(40):
        q = np.asarray(run_state.q)
        jax_state = env.step(jax_state, policy(jax_state.obs))
        action = r.step(q, target_pos)  # target_quat None: the task's
        run_state = env.step(run_state, jnp.asarray(action, jnp.float32))
        np.testing.assert_allclose(np.asarray(run_state.q), np.asarray(jax_state.q), atol=1e-4)
        steps.append(np.abs(action - q))
    assert float(jax_state.metrics["collisions"]) == 0  # no teleport to the reset pose
    assert np.mean(np.array(steps) < 0.045) > 0.05  # not only saturated steps
    np.testing.assert_allclose(np.asarray(run_state.obs), np.asarray(jax_state.obs), atol=1e-3)


def test_runner_file_imports_no_jax(exports, tmp_path):
    """runner.py, numpy_policy.py and ik_numpy.py copied into a folder and loaded by path,
    as on a robot: running both formats imports neither JAX, the mara_mjx package nor
    rclpy."""
    deploy = tmp_path / "robot"
    deploy.mkdir()
    for module in (runner, numpy_policy, ik_numpy):
        shutil.copy(module.__file__, deploy)
    code = textwrap.dedent(
        f"""
        import importlib.util, json, sys
        spec = importlib.util.spec_from_file_location("mara_runner", {str(deploy / "runner.py")!r})
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        out = {{}}
        for path in {[str(exports["finish.npz"]), str(exports["orient.onnx"])]!r}:
            r = mod.PolicyRunner.load(path)
            out[path] = r.step([0.1, -0.2, 0.3, 0.0, 0.5, 0.0], [-0.4, 0.1, 0.72]).tolist()
        heavy = [m for m in ("jax", "jaxlib", "mara_mjx", "rclpy", "flax") if m in sys.modules]
        print(json.dumps({{"heavy": heavy, "out": out}}))
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["heavy"] == []
    q = [0.1, -0.2, 0.3, 0.0, 0.5, 0.0]
    for path, action in report["out"].items():
        here = PolicyRunner.load(path).step(q, [-0.4, 0.1, 0.72])
        np.testing.assert_allclose(action, here, atol=1e-12)


def test_numpy_policy_restates_the_npz_format():
    """numpy_policy.py imports no mara_mjx module: its copies of the .npz format's
    constants are the package's (runtime/npzmeta.py)."""
    from mara_mjx.runtime import npzmeta

    assert numpy_policy.META_KEY == npzmeta.META_KEY
    assert numpy_policy._NPZ_ERRORS == npzmeta.NPZ_ERRORS


def test_bad_inputs_and_exports_are_refused(exports, tmp_path):
    """Wrong shapes, non-finite or non-numeric inputs, a changed batch size, foreign files
    and exports the runner cannot build the observation of: RunnerError naming what."""
    r = PolicyRunner.load(exports["orient.npz"])
    q, pos = np.zeros(6), np.array([-0.4, 0.1, 0.72])
    bad = [
        ((np.zeros(5), pos), "joint_positions must have shape \\(6,\\) or \\(N, 6\\)"),
        ((np.zeros((2, 3, 6)), pos), "joint_positions must have shape"),
        ((np.array([0, np.nan, 0, 0, 0, 0]), pos), "joint_positions has non-finite"),
        ((q, np.zeros(4)), "target_pos must have shape \\(3,\\) or \\(1, 3\\)"),
        ((np.zeros((2, 6)), np.zeros((3, 3))), "target_pos must have shape \\(3,\\) or \\(2, 3\\)"),
        ((q, [np.inf, 0, 0]), "target_pos has non-finite"),
        ((q, pos, np.zeros(4)), "non-zero quaternion"),
        ((q, pos, [1, 0, 0]), "target_quat must have shape"),
        ((["a"] * 6, pos), "joint_positions must be numeric"),
    ]
    for args, match in bad:
        with pytest.raises(RunnerError, match=match):
            r.step(*args)
    r.step(np.zeros((2, 6)), pos)
    with pytest.raises(RunnerError, match="call reset\\(\\)"):
        r.step(q, pos)  # the episode's batch is 2 arms
    r.reset()
    assert r.step(q, pos).shape == (6,)

    with pytest.raises(RunnerError, match=r"\.npz \(numpy\) or \.onnx \(onnxruntime\)"):
        PolicyRunner.load(tmp_path / "policy.pt")
    with pytest.raises(RunnerError, match="does not exist"):
        PolicyRunner.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(RunnerError, match="corrupt or not an exported"):
        PolicyRunner.load(tmp_path / "junk.npz")
    (tmp_path / "junk.onnx").write_bytes(b"not onnx")
    with pytest.raises(RunnerError, match="not an exported mara_mjx ONNX"):
        PolicyRunner.load(tmp_path / "junk.onnx")

    # an export whose observation has a part the runner does not build (a previous action)
    with np.load(exports["orient.npz"]) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["__meta__"]))
    layout = meta["observation_layout"]
    for edit, match in [
        (
            lambda m: m["observation_layout"].append(
                {"name": "prev_action", "start": 16, "stop": 22}
            ),
            "'prev_action'",
        ),
        (lambda m: m.update(observation_layout=layout[:-1]), "does not cover"),
        (lambda m: m.update(format="mara_mjx.export/9"), "format 'mara_mjx.export/9'"),
    ]:
        changed = json.loads(json.dumps(meta))
        edit(changed)
        arrays["__meta__"] = np.array(json.dumps(changed))
        np.savez(tmp_path / "edited.npz", **arrays)
        with pytest.raises(RunnerError, match=match):
            PolicyRunner.load(tmp_path / "edited.npz")


def test_a_file_of_a_fixed_batch_runs_any_number_of_rows():
    """`export --batch B`: evaluate's loop asks for N rows at once; the runner calls the
    file B rows at a time (the last call padded with the last row) and keeps row order."""
    calls = []

    def file(x):  # a graph of static batch 3: refuses any other
        assert x.shape == (3, 2), x.shape
        calls.append(len(x))
        return x[:, :1] * 2.0

    x = np.arange(14.0).reshape(7, 2)
    out = runner.in_batches(file, x, 3, 1)
    np.testing.assert_array_equal(out, x[:, :1] * 2.0)
    assert calls == [3, 3, 3]  # 7 rows: two full calls and one padded
    np.testing.assert_array_equal(runner.in_batches(file, x[:3], 3, 1), x[:3, :1] * 2.0)
    assert runner.in_batches(file, x[:0], 3, 1).shape == (0, 1)
    assert runner.in_batches(lambda r: r[:, :1], x, None, 1).shape == (7, 1)  # any batch
