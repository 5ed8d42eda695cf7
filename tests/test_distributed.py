"""Several processes (jax.distributed, gloo CPU collectives) train like one: the train CLI
as 2 processes of 1 CPU device each on localhost, against 1 process with 2 devices and 1
process with 1 device on the same global batch.

The env is the toy PointReach of test_ppo.py, registered in each subprocess, so that the
compiles stay small: what is under test is the multi-process plumbing of the CLI (joining,
process 0 writing, gathering checkpoints, resuming, config comparison, failure), which
does not depend on the env. Subprocesses share a JAX persistent compilation cache, so the
later 2-process runs reuse the first one's programs.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import FAST_COMPILE_FLAGS

from mara_mjx.cli.common import UserError
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.runtime import distributed

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
UPDATES = 3
TOY = [
    "--env", "PointReach",
    "--num_envs", "16",
    "--num_steps", "16",
    "--num_minibatches", "2",
    "--update_epochs", "2",
    "--learning_rate", "1e-2",
    "--lr_schedule", "constant",
    "--hidden_sizes", "16",
    "--total_timesteps", str(16 * 16 * UPDATES),
    "--updates_per_call", "1",
    "--checkpoint_every", "1",
    "--keep_checkpoints", "5",
    "--progress", "false",
    "--plots", "false",
    "--tensorboard", "false",
]  # fmt: skip

# A subprocess: the train CLI with the toy env registered (argv: tests folder, CLI flags),
# watched by its parent as `python -m mara_mjx.train` is (mara_mjx/runtime/supervise.py).
CLI = r"""
import sys
sys.path.insert(0, sys.argv[1])
from test_distributed import register_toy
register_toy()
from mara_mjx.cli import train
from mara_mjx.runtime import distributed, supervise
cli = lambda: distributed.run_cli(train.main, train.PROG, sys.argv[2:])
sys.exit(supervise.run(cli, train.PROG))
"""

# One process, 2 CPU devices: the toy config as the CLI resolves it, trained on 1 and on 2
# devices; prints the final params of both as JSON lists.
REFERENCE = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
from test_distributed import register_toy, TOY
register_toy()
import jax
import mara_mjx
from mara_mjx.cli import train
from mara_mjx.ppo import make_train
from mara_mjx.ppo import checkpoint as ckpt
assert jax.device_count() == 2, jax.devices()
plan = train.resolve(train.build_parser().parse_args(TOY + ["--out", "unused"]))
out = {}
for devices in (1, 2):
    trainer = make_train(mara_mjx.make("PointReach"), plan.config, 1, devices)
    state = trainer.init(jax.random.key(plan.config.ppo.seed))
    for _ in range(trainer.num_updates):
        state, _ = trainer.run(state, 1)
    arrays = ckpt.state_to_arrays(state)
    out[devices] = {k: v.tolist() for k, v in arrays.items() if k.startswith("params/")}
print(json.dumps(out))
"""


def register_toy() -> None:
    """Register 'PointReach' (test_ppo's toy, with the few extras the CLI reads)."""
    from test_ppo import PointReach

    import mara_mjx

    class ToyConfig:
        def to_dict(self) -> dict:
            return {}

    class CliPointReach(PointReach):
        config = ToyConfig()

        def reset(self, key, params=None):  # the evaluation reads orientation_error
            state = super().reset(key, params)
            return state.replace(metrics={**state.metrics, "orientation_error": jnp.zeros(3)})

    mara_mjx.register("PointReach", lambda **kw: CliPointReach(), overwrite=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def env_vars(tmp_path_factory) -> dict[str, str]:
    cache = tmp_path_factory.mktemp("jax_cache")
    env = {
        **os.environ,
        "JAX_PLATFORMS": "cpu",
        "MARA_MJX_COMPILATION_CACHE": str(cache),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0",
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
        "PYTHONUNBUFFERED": "1",
    }
    env["XLA_FLAGS"] = FAST_COMPILE_FLAGS  # as the suite (conftest.py), no device count
    for name in distributed.ENV_VARS.values():
        env.pop(name, None)
    return env


def start(env: dict[str, str], *args: str, **extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", CLI, str(TESTS), *args],
        cwd=REPO,
        env={**env, **extra},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def start_pair(env, args0: list[str], args1: list[str] | None = None, timeout: int = 20):
    """Processes 0 and 1 of a 2-process run (args1: process 1's flags, default args0)."""
    port = free_port()
    common = ["--num_processes", "2", "--join_timeout", str(timeout), "--heartbeat_timeout", "5"]
    procs = []
    for i, args in enumerate((args0, args0 if args1 is None else args1)):
        launch = ["--coordinator", f"localhost:{port}", "--process_id", str(i), *common]
        procs.append(start(env, *args, *launch))
    return procs


def finish(procs, timeout: float = 240) -> list[tuple[int, str, str]]:
    results = []
    for p in procs:
        try:
            out, err = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            for q in procs:
                q.kill()
            raise
        results.append((p.returncode, out, err))
    return results


def params_of(path: Path) -> dict[str, np.ndarray]:
    arrays, _ = ckpt.load_checkpoint(path)
    return {k: v for k, v in arrays.items() if k.startswith("params/")}


def max_diff(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> float:
    assert a.keys() == b.keys()
    return max(float(np.abs(np.asarray(a[k]) - np.asarray(b[k])).max()) for k in a)


@pytest.fixture(scope="module")
def runs(env_vars, tmp_path_factory):
    """The 2-process CLI run (process 1 given another --out, which it must not create)
    and, at the same time, the 1-process references."""
    base = tmp_path_factory.mktemp("distributed")
    out, elsewhere = base / "run", base / "process1-out"
    reference = subprocess.Popen(
        [sys.executable, "-c", REFERENCE, str(TESTS)],
        cwd=REPO,
        env={
            **env_vars,
            "XLA_FLAGS": f"--xla_force_host_platform_device_count=2 {FAST_COMPILE_FLAGS}",
        },
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    procs = start_pair(
        env_vars, [*TOY, "--out", str(out)], [*TOY, "--out", str(elsewhere)], timeout=120
    )
    results = finish(procs)
    ref_out, ref_err = reference.communicate(timeout=240)
    assert reference.returncode == 0, ref_err[-3000:]
    for code, _, err in results:
        assert code == 0, err[-3000:]
    ref = json.loads(ref_out.strip().splitlines()[-1])
    return out, elsewhere, results, {int(k): v for k, v in ref.items()}


def test_two_processes_train_like_one(runs):
    out, elsewhere, results, ref = runs
    final = params_of(out / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(UPDATES))
    first = params_of(out / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(1))
    assert max_diff(final, first) > 1e-3  # the params did train
    # measured (jax 0.10.2): 0 (the same partitioned program) and 1.2e-7
    assert max_diff(final, ref[2]) < 1e-6, "2 processes differ from 1 process x 2 devices"
    assert max_diff(final, ref[1]) < 1e-6, "2 processes differ from 1 process x 1 device"
    config = json.loads((out / "config.json").read_text())
    assert config["versions"]["devices"] == ["cpu", "cpu"]  # one device from each process


def test_only_process_zero_writes(runs):
    out, elsewhere, results, _ = runs
    (_, out0, _), (_, out1, _) = results
    assert not elsewhere.exists()  # process 1 ignores its --out: it writes nothing
    names = sorted(p.name for p in out.iterdir())
    assert names == ["checkpoints", "config.json", "eval.json", "progress.csv", "summary.json"]
    assert not [p for p in out.rglob("*") if ".tmp" in p.name or ".write-test" in p.name]
    rows = (out / "progress.csv").read_text().splitlines()
    assert len(rows) == 1 + UPDATES  # header + one row per update, written once
    assert "run folder: " in out0 and "Accuracy of the deterministic policy" in out0  # header
    assert "process 1 of 2: joined; process 0 writes the run folder" in out1
    assert "run folder: " not in out1 and "Accuracy" not in out1


def test_resume_with_two_processes(runs, env_vars, tmp_path):
    """Both processes read the same checkpoint and end where the uninterrupted run did."""
    out, _, _, _ = runs
    start_from = out / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(UPDATES - 1)
    resumed = tmp_path / "resumed"
    args = ["--resume", str(start_from), "--out", str(resumed), "--evaluate", "false"]
    for code, _, err in finish(start_pair(env_vars, args, timeout=60)):
        assert code == 0, err[-3000:]
    name = ckpt.checkpoint_name(UPDATES)
    new, _ = ckpt.load_checkpoint(resumed / ckpt.CHECKPOINT_DIR / name)
    old, _ = ckpt.load_checkpoint(out / ckpt.CHECKPOINT_DIR / name)
    assert new.keys() == old.keys()
    for k in old:  # the whole state: params, optimiser, env states of both processes, key
        if k != "__meta__":
            np.testing.assert_allclose(new[k], old[k], atol=1e-6, err_msg=k)
    assert len((resumed / "progress.csv").read_text().splitlines()) == 1 + UPDATES


def test_processes_that_disagree_stop_with_a_clear_error(env_vars, tmp_path):
    # process 1 with another learning rate: both stop before compiling the training
    procs = start_pair(
        env_vars, [*TOY, "--out", str(tmp_path / "a")], [*TOY, "--learning_rate", "2e-2"]
    )
    # ... and process 1 failing before the comparison (a missing checkpoint)
    missing = str(tmp_path / "missing")
    procs += start_pair(env_vars, [*TOY, "--out", str(tmp_path / "b")], ["--resume", missing])
    # ... and both asking for fewer devices than the processes have
    procs += start_pair(env_vars, [*TOY, "--out", str(tmp_path / "c"), "--devices", "1"])
    (c0, _, e0), (c1, _, e1), (c2, _, e2), (c3, _, e3), *devices = finish(procs, timeout=120)
    assert (c0, c1) == (2, 2), (e0[-2000:], e1[-2000:])
    for err in (e0, e1):
        assert "the processes disagree with process 0 on ppo (process 1)" in err
    assert (c2, c3) == (2, 2), (e2[-2000:], e3[-2000:])
    expected = f"CheckpointError: checkpoint or run folder {missing!r} does not exist"
    assert f"process 1 of 2 failed before training: {expected}" in e2, e2[-2000:]
    assert f"{missing!r} does not exist" in e3
    for code, _, err in devices:
        assert code == 2 and "devices=1 would leave out the devices of some of the 2" in err


def test_killing_a_process_stops_the_other(env_vars, tmp_path):
    """Process 1 killed once both have joined (process 0 is then compiling, or in its first
    collective): process 0, the coordinator, stops within the heartbeat timeout (5 s)
    instead of waiting for it forever."""
    procs = start_pair(env_vars, [*TOY, "--out", str(tmp_path / "run")], timeout=60)
    for line in procs[1].stdout:
        if "joined; process 0 writes the run folder" in line:
            break
    procs[1].send_signal(signal.SIGKILL)
    killed = time.monotonic()
    try:
        _, err = procs[0].communicate(timeout=60)
    finally:
        for p in procs:
            p.kill()
    seconds = time.monotonic() - killed
    assert procs[0].returncode not in (0, None), err[-3000:]
    assert seconds < 30, seconds
    # JAX ends it ("Terminating process because the JAX distributed service detected
    # fatal errors ... stopped sending heartbeats"), or a collective fails first
    assert "detected fatal errors" in err or "process 0 of 2 failed" in err, err[-3000:]
    assert not (tmp_path / "run" / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(1)).exists()


def test_killing_process_zero_ends_the_other_with_one_line(env_vars, tmp_path):
    """Process 0, the coordinator, killed (-9; its watched child dies with it): JAX aborts
    process 1 at once from C++ (SIGABRT, before any Python code runs); its watching parent
    (mara_mjx/runtime/supervise.py) ends it with one line naming process 0, status 1."""
    procs = start_pair(env_vars, [*TOY, "--out", str(tmp_path / "run")], timeout=60)
    for line in procs[1].stdout:
        if "joined; process 0 writes the run folder" in line:
            break
    procs[0].send_signal(signal.SIGKILL)
    killed = time.monotonic()
    try:
        _, err = procs[1].communicate(timeout=60)
    finally:
        for p in procs:
            p.kill()
    seconds = time.monotonic() - killed
    assert procs[1].returncode == 1, err[-3000:]  # (unwatched: -6, and a C++ stack trace)
    assert seconds < 10, seconds  # measured: 0.2-0.4 s
    last = err.strip().splitlines()[-1]
    assert last.startswith(
        "mara_mjx.train: error: JAX ended this process (SIGABRT) because process 0 "
        "(the coordinator, at localhost:"
    ), err[-3000:]


# Two processes build the MARA env: every array it holds must be on this process's device
# (MJX's default device, jax.devices()[0], is process 0's; process 1 then failed to
# compile anything that closed over the model).
LOCAL_ARRAYS = r"""
import sys
import jax
jax.distributed.initialize(f"localhost:{sys.argv[1]}", 2, int(sys.argv[2]),
                           initialization_timeout=60, heartbeat_timeout_seconds=5)
import mara_mjx
env = mara_mjx.make("MARA")
arrays = [x for x in jax.tree.leaves((env.arm.mjx_model, env.arm._data0, env.make_params()))
          if isinstance(x, jax.Array)]
remote = [x.shape for x in arrays if not x.is_fully_addressable]
assert arrays and not remote, remote
print("local", len(arrays))
"""


def test_env_arrays_live_on_the_local_device(env_vars):
    port = str(free_port())
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", LOCAL_ARRAYS, port, str(i)],
            cwd=REPO,
            env=env_vars,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    for code, out, err in finish(procs, timeout=120):
        assert code == 0 and "local" in out, err[-3000:]


def launch(argv: list[str], environ: dict[str, str] | None = None):
    parser = argparse.ArgumentParser()
    distributed.add_arguments(parser)
    return distributed.launch_from(parser.parse_args(argv), environ or {})


def test_launch_settings():
    assert launch([]) is None  # one process
    assert launch(["--num_processes", "1"]) is None
    got = launch(["--coordinator", "h:1234", "--num_processes", "2", "--process_id", "1"])
    assert (got.coordinator, got.num_processes, got.process_id) == ("h:1234", 2, 1)
    env = {"MARA_COORDINATOR": "h:99", "MARA_NUM_PROCESSES": "4", "MARA_PROCESS_ID": "3"}
    got = launch([], env)
    assert (got.coordinator, got.num_processes, got.process_id, got.source) == (
        "h:99",
        4,
        3,
        "flags",
    )
    assert launch(["--process_id", "0"], env).process_id == 0  # flags win over variables
    slurm_partial = launch(["--coordinator", "h:1"], {"SLURM_JOB_ID": "7", "SLURM_NTASKS": "2"})
    assert slurm_partial.coordinator == "h:1" and slurm_partial.process_id is None
    slurm = {"SLURM_JOB_ID": "7", "SLURM_NTASKS": "2"}
    assert launch([], slurm).source == "slurm" and launch([], slurm).coordinator is None
    assert launch([], {**slurm, "SLURM_NTASKS": "1"}) is None
    assert launch(["--distributed", "off"], slurm) is None
    assert launch([], {**slurm, "MARA_DISTRIBUTED": "off"}) is None
    bad = {
        "is not HOST:PORT": (["--coordinator", "nohost"], {}),
        "process_id=2 is out of range; choose 0..1": (
            ["--num_processes", "2", "--process_id", "2"],
            {},
        ),  # noqa: E501
        "num_processes must be >= 1": (["--num_processes", "0"], {}),
        "MARA_PROCESS_ID='x' is not an integer": ([], {"MARA_PROCESS_ID": "x"}),
        "heartbeat_timeout must be >= 1": (["--heartbeat_timeout", "0"], {}),
        "distributed mode 'on' is invalid": ([], {"MARA_DISTRIBUTED": "on"}),
        "missing: num_processes, process_id": (["--coordinator", "h:1"], {}),
    }
    for message, (argv, environ) in bad.items():
        with pytest.raises(UserError, match=message.replace("(", r"\(")):
            launch(argv, environ)


def test_single_process_is_untouched():
    assert not distributed.active() and distributed.is_main()
    tree = {"x": jnp.ones(3)}
    assert distributed.gather(tree) is tree
    distributed.check_same({"a": 1})  # no-op
    distributed.barrier("nothing")
