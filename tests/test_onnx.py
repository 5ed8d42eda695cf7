"""ONNX export (`python -m mara_mjx.export CHECKPOINT policy.onnx`): onnxruntime against
the JAX policy (make_policy) on random observations, to 1e-5. Skipped without the
optional `[onnx]` extra."""

from __future__ import annotations

import json
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest
from test_export_plots import make_run

from mara_mjx.cli.export import export_policy
from mara_mjx.ppo import make_policy

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")


@pytest.mark.parametrize(
    ("env_name", "normalize", "relative", "canonical", "step"),
    [("MARA", True, False, False, 0.0), ("MARAOrient", True, True, True, 0.05)],
)
def test_onnx_policy_matches_the_jax_policy(
    tmp_path, env_name, normalize, relative, canonical, step
):
    quat = {"canonical_quat": True, "quat_index": 9} if canonical else {}
    path = make_run(
        tmp_path / "run", env_name, normalize, relative=relative, max_joint_step=step, **quat
    )
    out = export_policy(tmp_path / "run", tmp_path / "policy.onnx")
    model = onnx.load(str(out))
    ops = {n.op_type for n in model.graph.node}
    assert {"MatMul", "Tanh", "Sub", "Div", "Clip"} <= ops
    assert ("Where" in ops) == canonical
    meta = json.loads({p.key: p.value for p in model.metadata_props}["mara_mjx"])
    assert meta["quat_index"] == (9 if canonical else -1) and meta["env_name"] == env_name

    reference = make_policy(path)
    size = 16 if "Orient" in env_name else 12
    obs = np.random.default_rng(2).normal(0.0, 3.0, (256, size)).astype(np.float32)
    obs[:8] *= 100.0  # beyond obs_clip after normalisation
    if canonical:  # both signs of w, and w exactly 0 (counts as positive)
        obs[::2, 9] = -np.abs(obs[::2, 9])
        obs[1::4, 9] = 0.0
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    action, clipped = session.run(["action", "action_clipped"], {"obs": obs})
    expected = np.asarray(reference(jnp.asarray(obs)))
    assert np.abs(expected).max() > 0.1  # not the near-zero init: the check has teeth
    np.testing.assert_allclose(action, expected, atol=1e-5, rtol=0)
    if step:  # max_joint_step squashes the joint displacement
        assert 0.5 * step < np.abs(action - obs[:, :6]).max() <= step + 1e-4
    lower, upper = np.asarray(meta["action"]["lower"]), np.asarray(meta["action"]["upper"])
    np.testing.assert_allclose(clipped, np.clip(expected, lower, upper), atol=1e-5, rtol=0)
    one = session.run(["action"], {"obs": obs[:1]})[0]
    np.testing.assert_allclose(one, expected[:1], atol=1e-5, rtol=0)
    if canonical:  # the sign fix matters: flipping the quaternion leaves the action alone
        flipped = obs.copy()
        flipped[:, 9:13] *= -1.0
        flipped[obs[:, 9] == 0.0, 9:13] *= -1.0  # w = 0 is canonical either way round
        again = session.run(["action"], {"obs": flipped})[0]
        mask = obs[:, 9] != 0.0
        np.testing.assert_allclose(again[mask], action[mask], atol=1e-6)


def test_export_cli_writes_onnx(tmp_path):
    make_run(tmp_path / "run", "MARA", True)
    out = tmp_path / "policy.onnx"
    result = subprocess.run(
        [sys.executable, "-m", "mara_mjx.export", str(tmp_path / "run"), str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert "ONNX" in result.stdout and out.is_file()
    onnx.checker.check_model(onnx.load(str(out)))
