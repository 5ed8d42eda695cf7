"""The benchmark CLI (env and peers studies, as subprocesses) and the brax adapter."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State
from brax.envs.wrappers.training import wrap

import mara_mjx
from mara_mjx.brax_env import METRICS, NEVER, BraxMaraEnv, make_brax_env

ROOT = Path(__file__).resolve().parents[1]
META_KEYS = {"study", "command", "versions", "device", "config", "date", "records"}


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "mara_mjx.benchmark", *args]


def _popen(args: list[str]) -> subprocess.Popen:
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.Popen(
        args, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Start both quick studies at once (they overlap the in-process brax tests)."""
    out = tmp_path_factory.mktemp("bench")
    procs = {
        "env": _popen(
            _cli("env", "--quick", "--tasks", "MARA", "--drivers", "train", "--out", str(out))
        ),
        "peers": _popen(_cli("peers", "--quick", "--skip-mjx", "--out", str(out))),
    }
    return out, procs


def _finish(runs, study: str) -> dict:
    out, procs = runs
    proc = procs[study]
    text, _ = proc.communicate(timeout=240)
    assert proc.returncode == 0, text
    for ext in ("json", "md", "png"):
        assert (out / f"{study}.{ext}").is_file()
    return json.loads((out / f"{study}.json").read_text())


# ----------------------------------------------------------------- brax adapter
@pytest.fixture(scope="module")
def brax_env(runs) -> BraxMaraEnv:  # `runs` first: the subprocesses start before compiling
    return make_brax_env("MARA")


def test_brax_adapter_matches_mara_env(brax_env):
    env = mara_mjx.make("MARA", max_episode_steps=NEVER)
    assert brax_env.observation_size == env.observation_size == 12
    assert brax_env.action_size == 6 and brax_env.backend == "mjx"
    a = jnp.array([-1.0, -0.5, 0.0, 0.25, 0.5, 1.0])
    q_cmd = brax_env.to_joint_targets(a)
    lo, hi = env.joint_lower, env.joint_upper
    np.testing.assert_allclose(q_cmd, lo + (a + 1) / 2 * (hi - lo), rtol=1e-6)

    @jax.jit
    def both(key):  # one compile: reset both, then two steps of each in a scan
        def body(carry, _):
            bs, es = carry
            bs, es = brax_env.step(bs, a), env.step(es, q_cmd)
            return (bs, es), (bs, es)

        first = (brax_env.reset(key), env.reset(key))
        return first, jax.lax.scan(body, first, None, length=2)[1]

    (bs0, es0), (bs, es) = both(jax.random.PRNGKey(3))
    assert isinstance(bs0, State)
    np.testing.assert_allclose(bs0.obs, es0.obs)
    assert set(bs.metrics) == set(METRICS)
    np.testing.assert_allclose(bs.obs, es.obs, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(bs.reward, es.reward, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(bs.done, 0.0)
    np.testing.assert_allclose(bs.metrics["distance"], es.metrics["distance"], rtol=1e-6)
    np.testing.assert_allclose(
        bs.metrics["position_error_y"], es.metrics["position_error"][:, 1], rtol=1e-6
    )
    assert all(v.shape == (2,) for v in bs.metrics.values())  # () per step, stacked


def test_brax_wrap_truncates_at_episode_length(brax_env):
    w = wrap(brax_env, episode_length=3)
    state = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(w.step)
    action = jnp.zeros((2, 6))
    dones, truncs = [], []
    for _ in range(4):
        state = step(state, action)
        dones.append(np.asarray(state.done).tolist())
        truncs.append(np.asarray(state.info["truncation"]).tolist())
    assert dones == [[0, 0], [0, 0], [1, 1], [0, 0]]  # done at the horizon, then auto-reset
    assert truncs == [[0, 0], [0, 0], [1, 1], [0, 0]]  # a truncation: brax's GAE bootstraps
    assert state.info["episode_metrics"]["distance"].shape == (2,)


def test_brax_adapter_rejects_mara_horizon():
    with pytest.raises(ValueError, match="episode_length"):
        make_brax_env("MARA", max_episode_steps=10)
    with pytest.raises(ValueError, match="episode_length"):
        make_brax_env("MARA", episode_length=0)
    with pytest.raises(ValueError, match="unknown env"):
        make_brax_env("NoSuchTask")


# ------------------------------------------------------------------- the CLI
def test_env_study_quick(runs):
    data = _finish(runs, "env")
    assert META_KEYS <= set(data) and data["study"] == "env"
    (rec,) = data["records"]
    assert rec["task"] == "MARA" and rec["driver"] == "train" and rec["num_envs"] == 4
    assert rec["env_steps_per_s"] > 0 and rec["physics_steps_per_s"] is None


def test_peers_study_quick(runs):
    data = _finish(runs, "peers")
    assert META_KEYS <= set(data) and data["study"] == "peers"
    (rec,) = data["records"]
    assert rec["impl"].startswith("mujoco C rollout")
    assert rec["num_envs"] == 4 and rec["substeps"] == 10
    assert rec["physics_steps_per_s"] == pytest.approx(10 * rec["env_steps_per_s"])
    assert "mjx_over_c" in rec


@pytest.mark.parametrize(
    "args, message",
    [
        (["nostudy"], "invalid choice"),
        (["env", "--tasks", "NoSuchTask"], "unknown task"),
        (["env", "--out", "/proc/forbidden"], "not writable"),
    ],
)
def test_bad_input_gives_clear_error(args, message):
    proc = subprocess.run(
        _cli(*args),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )
    assert proc.returncode == 2
    assert message in proc.stderr
