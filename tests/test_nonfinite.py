"""Non-finite policies (issue 34 item 7): a training run whose parameters or loss stop
being finite stops with one message and a non-zero exit, keeping its last finite
checkpoint (mara_mjx.ppo.divergence); evaluate, play and export refuse a checkpoint
whose policy is not finite (mara_mjx.ppo.policy.policy_from_checkpoint).

One tiny training run (its second call's parameters poisoned with NaN) serves all.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mara_mjx.cli import evaluate as evaluate_cli
from mara_mjx.cli import export as export_cli
from mara_mjx.cli import play as play_cli
from mara_mjx.cli.common import run_cli
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import divergence

REPO = Path(__file__).resolve().parents[1]
TINY = [
    "--env", "MARA",
    "--num_envs", "4",
    "--num_steps", "8",
    "--total_timesteps", "96",
    "--num_minibatches", "2",
    "--update_epochs", "2",
    "--max_episode_steps", "16",
    "--checkpoint_every", "1",
    "--updates_per_call", "1",
    "--progress", "false",
    "--tensorboard", "false",
    "--plots", "false",
]  # fmt: skip

# The train CLI with its jitted `run` wrapped (after warmup.traced, as the loop calls it):
# from the second call on, the returned state's params are NaN (a divergence).
POISONED = """
import sys
import jax, jax.numpy as jnp
from mara_mjx.cli import train
from mara_mjx.runtime import distributed
from mara_mjx.ppo import warmup
traced = warmup.traced
def poisoned(trainer, state, seed):
    trainer = traced(trainer, state, seed)
    run, calls = trainer.run, []
    def run_then_poison(state, n):
        state, metrics = run(state, n)
        calls.append(n)
        if len(calls) >= 2:
            state = state.replace(params=jax.tree.map(lambda x: x * jnp.nan, state.params))
        return state, metrics
    return trainer._replace(run=run_then_poison)
warmup.traced = poisoned
sys.exit(distributed.run_cli(train.main, train.PROG, sys.argv[1:]))
"""


@pytest.fixture(scope="module")
def diverged(tmp_path_factory):
    """(run folder, completed process) of the poisoned run."""
    out = tmp_path_factory.mktemp("diverged") / "run"
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "MARA_MJX_COMPILATION_CACHE": "0"}
    proc = subprocess.run(
        [sys.executable, "-c", POISONED, *TINY, "--out", str(out)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    return out, proc


def test_diverged_training_stops_with_a_message_keeping_the_finite_checkpoint(diverged):
    out, proc = diverged
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("mara_mjx.train: error: training diverged in updates 2-2: params")
    assert "not finite" in last and "--resume" in last
    saved = ckpt.list_checkpoints(out)
    assert [p.name for p in saved] == [ckpt.checkpoint_name(1)]  # not update 2's state
    arrays, _ = ckpt.load_checkpoint(saved[0])
    assert all(np.all(np.isfinite(v)) for k, v in arrays.items() if k.startswith("params/"))
    assert not (out / "eval.json").exists() and not (out / "summary.json").exists()


@pytest.fixture(scope="module")
def nan_checkpoint(diverged, tmp_path_factory):
    """The finite checkpoint of the run with one policy array set to NaN."""
    out, _ = diverged
    arrays, meta = ckpt.load_checkpoint(ckpt.list_checkpoints(out)[-1])
    name = next(k for k in arrays if k.startswith("params/") and k.endswith("kernel"))
    arrays[name] = np.full_like(arrays[name], np.nan)
    folder = tmp_path_factory.mktemp("nan_run")
    path = folder / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(1)
    ckpt.save_checkpoint(path, arrays, meta)
    return path, name


@pytest.mark.parametrize("cli", ["evaluate", "play", "export"])
def test_a_checkpoint_with_nan_params_is_refused(cli, nan_checkpoint, tmp_path, capsys):
    path, name = nan_checkpoint
    main, prog, argv = {
        "evaluate": (evaluate_cli.main, evaluate_cli.PROG, [str(path)]),
        "play": (play_cli.main, play_cli.PROG, [str(path), "--episodes", "1"]),
        "export": (export_cli.main, export_cli.PROG, [str(path), str(tmp_path / "p.npz")]),
    }[cli]
    assert run_cli(main, prog, argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{prog}: error: the checkpoint's policy is not finite"), err
    assert name in err and err.count("\n") == 1
    assert not (tmp_path / "p.npz").exists()


def test_check_finite_names_the_loss_and_the_arrays():
    class State:
        params = {"actor": {"kernel": np.ones(3, np.float32)}}
        obs_stats = None

    divergence.check_finite(State(), {"loss": np.float32(1.0), "distance_mm": np.nan}, 0, 2)
    with pytest.raises(divergence.Diverged, match=r"updates 5-6: loss not finite"):
        divergence.check_finite(State(), {"loss": np.array([1.0, np.inf])}, 4, 2)
    State.params["actor"]["kernel"][1] = np.nan
    with pytest.raises(SystemExit) as e:
        divergence.check_finite(State(), {"loss": 1.0}, 0, 1)
    assert "params['actor']['kernel'] not finite" in str(e.value.code)


def test_a_call_shorter_than_updates_per_call_is_not_divergence():
    """The last call of a run whose updates are not a multiple of updates_per_call skips
    its remaining iterations, whose metric rows are NaN and not valid (ppo.train's skip):
    every default-preset run ends so (762 updates, 10 per call)."""

    class State:
        params = {"actor": {"kernel": np.ones(3, np.float32)}}
        obs_stats = None

    loss = np.array([[1.0, 2.0, np.nan], [0.5, 0.1, np.nan]])  # (seeds, updates_per_call)
    valid = np.array([[True, True, False], [True, True, False]])
    divergence.check_finite(State(), {"loss": loss, "valid": valid}, 760, 2)
    members = np.stack([loss, loss], -1)  # a population's members on a last axis
    divergence.check_finite(State(), {"policy_loss": members, "valid": valid}, 760, 2)
    loss[1, 1] = np.nan  # a real divergence in a valid row still stops the run
    with pytest.raises(divergence.Diverged, match="loss not finite"):
        divergence.check_finite(State(), {"loss": loss, "valid": valid}, 760, 2)


def test_a_population_stops_only_when_every_member_diverged():
    """PBT's exploit step replaces a diverged member (NaN fitness ranks last)."""

    class Population:
        fitness = np.zeros(3, np.float32)
        params = {"w": np.ones((3, 4), np.float32)}
        obs_stats = {"mean": np.zeros((3, 2), np.float32)}

    state = Population()
    state.params["w"][1, 2] = np.nan
    divergence.check_finite(state, {"loss": np.nan}, 0, 1)  # member 0's loss: not alone
    state.params["w"][0, 0] = np.inf
    state.obs_stats["mean"][2, 1] = np.nan
    with pytest.raises(divergence.Diverged, match="every member"):
        divergence.check_finite(state, {"loss": 1.0}, 0, 1)
