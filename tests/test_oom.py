"""Out of memory under an address-space limit (issue 34 item 10): the train CLI ends with
one message and exit status 1 in bounded time. It used to hang at exit: XLA raised
RESOURCE_EXHAUSTED, but closing the TensorBoard writer needed a new thread (its queue's
feeder), which the limit refused, and tensorboardX's atexit cleanup then waited forever
for its writer thread (benchmarks/NOTES.md has the stacks)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# The train CLI whose first jitted call is replaced by: RLIMIT_AS set to the process's
# address space plus 4 MiB (no 8 MiB thread stack fits), then a 4 GiB array (XLA's
# RESOURCE_EXHAUSTED, raised from the loop's device_get as in a real run).
OUT_OF_MEMORY = """
import resource, sys
import jax.numpy as jnp
from mara_mjx.cli import train
from mara_mjx.runtime import distributed
from mara_mjx.ppo import warmup
traced = warmup.traced
def vm_bytes():
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmSize:"))
def out_of_memory(trainer, state, seed):
    trainer = traced(trainer, state, seed)
    def run(state, n):  # compiles and runs under the limit, as a first call does
        limit = vm_bytes() + (4 << 20)
        resource.setrlimit(resource.RLIMIT_AS, (limit, resource.RLIM_INFINITY))
        return state, {"x": jnp.zeros((1 << 30,), jnp.float32)}
    return trainer._replace(run=run)
warmup.traced = out_of_memory
sys.exit(distributed.run_cli(train.main, train.PROG, sys.argv[1:]))
"""
TINY = [
    "--env", "MARA",
    "--num_envs", "4",
    "--num_steps", "8",
    "--total_timesteps", "64",
    "--num_minibatches", "2",
    "--update_epochs", "2",
    "--max_episode_steps", "16",
    "--progress", "false",
    "--plots", "false",
]  # fmt: skip


def test_out_of_memory_ends_with_a_message_not_a_hang(tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "MARA_MJX_COMPILATION_CACHE": "0"}
    proc = subprocess.run(  # with TensorBoard on, as by default
        [sys.executable, "-c", OUT_OF_MEMORY, *TINY, "--out", str(tmp_path / "run")],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=240,  # the hang never ended; the run itself takes ~10 s of CPU
    )
    assert proc.returncode == 1, proc.stderr[-3000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("mara_mjx.train: error: out of memory: RESOURCE_EXHAUSTED"), last
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]


# The train CLI as `python -m mara_mjx.train` runs it (watched: mara_mjx/runtime/supervise.py),
# its first jitted call compiling under RLIMIT_AS = the process's size + 128 MiB: LLVM
# aborts the compile ("LLVM ERROR: Unable to allocate section memory"; at + 64 MiB
# libstdc++'s std::bad_alloc), SIGABRT, before any Python code can run.
COMPILE_OUT_OF_MEMORY = """
import resource, sys
from mara_mjx.cli import train
from mara_mjx.runtime import distributed, supervise
from mara_mjx.ppo import warmup
traced = warmup.traced
def vm_bytes():
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmSize:"))
def out_of_memory(trainer, state, seed):
    trainer = traced(trainer, state, seed)
    compile_and_run = trainer.run
    def run(state, n):
        limit = vm_bytes() + (128 << 20)
        resource.setrlimit(resource.RLIMIT_AS, (limit, resource.RLIM_INFINITY))
        return compile_and_run(state, n)
    return trainer._replace(run=run)
warmup.traced = out_of_memory
cli = lambda: distributed.run_cli(train.main, train.PROG, sys.argv[1:])
sys.exit(supervise.run(cli, train.PROG))
"""


def test_a_compile_out_of_memory_ends_with_one_line(tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "MARA_MJX_COMPILATION_CACHE": "0"}
    env.pop("MARA_MJX_SUPERVISE", None)
    proc = subprocess.run(
        [sys.executable, "-c", COMPILE_OUT_OF_MEMORY, *TINY, "--out", str(tmp_path / "run")],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=240,  # ~12 s
    )
    # unwatched: status -6 (SIGABRT) and LLVM's line last
    assert proc.returncode == 1, proc.stderr[-3000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("mara_mjx.train: error: out of memory"), proc.stderr[-3000:]
