"""Training over several devices matches one device (CPU: 4 forced host devices).

XLA's device count is fixed when jax starts, so the check runs in a fresh process with
XLA_FLAGS=--xla_force_host_platform_device_count=4 (the toy task of test_ppo.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import FAST_COMPILE_FLAGS

from mara_mjx.runtime import sharding

SCRIPT = r"""
import json, re, sys
import jax, numpy as np
sys.path.insert(0, sys.argv[1])
from test_ppo import PointReach, TOY_CONFIG
from mara_mjx.ppo import make_train

assert jax.device_count() == 4, jax.devices()
config = TOY_CONFIG.replace(total_timesteps=16 * 16 * 3)
results = {}
for devices in (1, 4):
    trainer = make_train(PointReach(), config, updates_per_call=3, devices=devices)
    state = trainer.init(jax.random.key(0))
    n_env = len(state.env_state.obs.sharding.device_set)
    state, metrics = trainer.run(state, 3)
    results[devices] = (jax.device_get(state), jax.device_get(metrics), n_env,
                        len(state.env_state.obs.sharding.device_set))
    if devices == 4:  # the SGD's gradient all-reduce: one flat buffer of every parameter
        hlo = trainer.run.lower(state, 3).compile().as_text()
        n_params = sum(x.size for x in jax.tree.leaves(state.params))
        reduces = [l for l in hlo.splitlines() if re.search(r" all-reduce(-start)?\(", l)]
        flat_grad = any(f"f32[{n_params}]" in l for l in reduces)
# more minibatches than steps: minibatches cut from env groups (2 per device here)
groups = config.replace(num_steps=4, num_minibatches=8, total_timesteps=16 * 4 * 2)
group_params = []
for devices in (1, 4):
    trainer = make_train(PointReach(), groups, updates_per_call=2, devices=devices)
    state, _ = trainer.run(trainer.init(jax.random.key(1)), 2)
    group_params.append(jax.tree.leaves(jax.device_get(state.params)))
group_diff = max(float(np.abs(a - b).max()) for a, b in zip(*group_params))
(s1, m1, e1, f1), (s4, m4, e4, f4) = results[1], results[4]
params = jax.tree.leaves(s1.params), jax.tree.leaves(s4.params)
param_diff = max(float(np.abs(a - b).max()) for a, b in zip(*params))
obs_diff = float(np.abs(s1.env_state.obs - s4.env_state.obs).max())
metric_diff = max(float(np.nanmax(np.abs(m1[k] - m4[k]))) for k in
                  ("reward_mean", "policy_loss", "value_loss", "det_error_mm", "grad_norm"))
changed = max(float(np.abs(a).max()) for a in params[0])
errors = []
for devices, envs, minibatches in ((4, 6, 2), (4, 16, 128), (5, 16, 4)):
    try:
        make_train(PointReach(), config.replace(num_envs=envs, num_minibatches=minibatches),
                   devices=devices)
        errors.append(None)
    except ValueError as e:
        errors.append(str(e))
print(json.dumps({"devices": [e1, f1, e4, f4], "param_diff": param_diff, "obs_diff": obs_diff,
                  "metric_diff": metric_diff, "errors": errors, "changed": changed,
                  "group_diff": group_diff, "flat_grad": flat_grad}))
"""


@pytest.fixture(scope="module")
def four_devices():
    env = {
        **os.environ,
        "XLA_FLAGS": f"--xla_force_host_platform_device_count=4 {FAST_COMPILE_FLAGS}",
    }
    env["JAX_PLATFORMS"] = "cpu"
    tests = str(Path(__file__).resolve().parent)
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, tests],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_sharded_training_matches_one_device(four_devices):
    r = four_devices
    assert r["devices"] == [1, 1, 4, 4]  # env state on 4 devices before and after training
    assert r["changed"] > 0.01  # the params did train
    assert r["param_diff"] < 1e-5, r
    assert r["obs_diff"] < 1e-5, r
    assert r["metric_diff"] < 1e-4, r
    assert r["group_diff"] < 1e-5, r
    assert r["flat_grad"], "the gradients are no longer all-reduced as one flat buffer"


def test_invalid_device_combinations_are_clear_errors(four_devices):
    envs, minibatch, too_many = four_devices["errors"]
    assert envs is not None and "num_envs=6 is not divisible by the 4 devices" in envs
    # 128 minibatches of 16 steps: 8 env groups, but only 4 envs per device
    assert minibatch is not None and "8 groups of environments" in minibatch
    assert "4 environments per device" in minibatch and "multiple of 8" in minibatch
    assert too_many is not None and "only 4 cpu device(s)" in too_many


def test_device_count_validation():
    assert sharding.device_count(None) >= 1
    assert sharding.make_mesh(1) is None
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="devices must be an int"):
            sharding.device_count(bad)


def test_scaling_study_helpers():
    from mara_mjx.bench.scaling import add_efficiency, device_counts

    assert device_counts(None)[0] == 1 and device_counts([1]) == [1]
    with pytest.raises(ValueError, match="not available"):
        device_counts([sharding.device_count() + 1])
    records = [
        {"part": "env", "scaling": "weak", "devices": 1, "env_steps_per_s": 10.0},
        {"part": "env", "scaling": "weak", "devices": 2, "env_steps_per_s": 18.0},
        {"part": "ppo", "scaling": "strong", "devices": 4, "env_steps_per_s": 20.0},
    ]
    add_efficiency(records)
    assert [r["efficiency"] for r in records] == [1.0, 0.9, None]
