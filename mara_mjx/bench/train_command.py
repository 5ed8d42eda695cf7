"""The user's train command as a fresh process, for the studies that train through it
(`tta`, `robustness`): its extra flags checked, the user's environment put back, the
command launched and timed, and its run folder read back on the launch clock.

`check_train_args` refuses flags the train CLI does not accept or the study sets itself
(`SET_BY_STUDY`); `child_env` is this process's environment with the variables the
benchmark runner changed as the user gave them (`runner.USER_ENV`); `launch` runs one
command to its end or its time limit; `read_run` reads a finished run folder
(progress.csv, summary.json and `state_hash` of its final checkpoint). `QUIET` are the
flags every such command gets (no evaluation, plots, TensorBoard or progress bar).

Clocks. "From command start" is from the moment this process launches the subprocess
(`time.monotonic()` just before `subprocess.Popen`). The CLI's own times (progress.csv's
`time_s`, summary.json's `time_to_accuracy` and `command_time_s`) count from its
process's start as the kernel records it (`mara_mjx.cli.train._command_start`: /proc/PID/stat,
so interpreter start-up and imports count). `launch` reads the child's start the same
way right after launching it; `launch_offset_s` = child's start - launch (milliseconds;
slightly negative is possible, since /proc rounds the start down to a clock tick, the
same rounding as the CLI's, so it cancels) is added to every CLI time. Without /proc
(not Linux) the CLI counts from its own import and the offset is unknown (None, taken as
0: the times are then too short by the interpreter's start-up). `command_s` is launch to
exit (interpreter teardown included), measured here; `cli_command_time_s` is the CLI's
own (until it wrote summary.json), converted.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shlex
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np

from mara_mjx.bench.runner import USER_ENV
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import logger

QUIET = ["--evaluate", "false", "--plots", "false", "--tensorboard", "false", "--progress", "false"]
"""As the hand-made measurement (benchmarks/results/time_to_accuracy/README.md)."""
SET_BY_STUDY = (
    *("--env", "--seed", "--ppo.seed", "--seeds", "--run.seeds", "--out", "--run.out"),
    *("--compilation_cache", "--resume", "--preset", "-h", "--help"),
)
THRESHOLDS_MM = logger.ACCURACY_THRESHOLDS_MM  # (5, 1): the CLI's milestones


def check_train_args(text: str, task: str, preset: str, build_env: bool = False) -> None:
    """ValueError unless `text` is flags the train CLI accepts and the study does not set;
    with `build_env`, also unless the env they describe builds. Building an env starts
    JAX's backend, so the config's own check leaves it to `tta_study`: the benchmark
    parser makes every study's default config before `runner.configure` sets up the
    backend (and without that, this process would preallocate the GPU memory that the
    train commands it launches need: they then fail to compile)."""
    import mara_mjx
    from mara_mjx.cli import train as train_cli
    from mara_mjx.cli.common import UserError

    try:
        args = shlex.split(text)
    except ValueError as e:
        raise ValueError(f"train_args: {e}") from e
    taken = [a for a in args if a.split("=")[0] in SET_BY_STUDY]
    if taken:
        raise ValueError(f"train_args: the study sets {', '.join(taken)} itself")
    parser = train_cli.build_parser([])  # (not this process's own argv)

    def fail(message: str) -> None:
        raise ValueError(f"train_args: {message}")

    parser.error = fail  # argparse reports bad flags through error(); no exit here
    argv = ["--env", task, *(["--preset", preset] if preset else []), *QUIET, *args]
    try:
        plan = train_cli.resolve(parser.parse_args(argv))
    except UserError as e:
        raise ValueError(f"train_args: {e}") from e
    if not build_env:
        return
    try:  # as the CLI builds it (cheap: nothing compiles)
        mara_mjx.make(plan.env_name, **plan.env_overrides)
    except ValueError as e:
        raise ValueError(f"train_args: cannot build env {plan.env_name}: {e}") from e


# ------------------------------------------------------------------- one command
def child_env(xla_ops: str | None = None) -> dict[str, str]:
    """This process's environment with the variables the runner changed put back as the
    user gave them; `xla_ops` ("true"/"false"): --xla_gpu_deterministic_ops set so."""
    env = dict(os.environ)
    for name, value in USER_ENV.items():
        if value is None:
            env.pop(name, None)
        else:
            env[name] = value
    if xla_ops is not None:
        flags = env.get("XLA_FLAGS", "").split()
        flags = [f for f in flags if "xla_gpu_deterministic_ops" not in f]
        env["XLA_FLAGS"] = " ".join([*flags, f"--xla_gpu_deterministic_ops={xla_ops}"])
    return env


def launch(argv: list[str], env: dict[str, str], log: Path, timeout_s: float) -> dict[str, Any]:
    """Run `argv` (output to `log`); `launch_offset_s` and `command_s` (module docstring).
    RuntimeError with the end of its output if it fails or runs out of time."""
    from mara_mjx.cli.train import _command_start

    with open(log, "w") as f:
        t0 = time.monotonic()
        proc = subprocess.Popen(argv, env=env, stdout=f, stderr=subprocess.STDOUT)
        offset = _command_start(proc.pid) - t0 if os.path.exists(f"/proc/{proc.pid}") else None
        try:
            code = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            code = None
        finally:  # timed out, or this process interrupted: no training left behind
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        command_s = time.monotonic() - t0
    if code != 0:
        why = f"exit status {code}" if code is not None else f"killed after {timeout_s} s"
        tail = log.read_text()[-3000:]
        raise RuntimeError(f"{shlex.join(argv)}: {why}; its output ends:\n{tail}")
    return {"launch_offset_s": offset, "command_s": command_s}


def read_run(run_dir: Path, offset: float | None) -> dict[str, Any]:
    """What a finished run folder says, with the CLI's times moved to the launch clock."""
    shift = offset or 0.0
    progress = logger.read_progress(run_dir, ("env_steps", "time_s", "steps_per_s"))
    summary = json.loads((run_dir / "summary.json").read_text())
    t, sps = progress["time_s"], progress["steps_per_s"]
    later = sps[(t > t[0]) & np.isfinite(sps)]
    det = progress.get("det_error_mm", np.array([math.nan]))[-1]
    out: dict[str, Any] = {
        "env_steps": int(progress["env_steps"][-1]),
        "first_call_s": float(t[0]) + shift,
        "env_steps_per_s": float(np.median(later)) if later.size else None,
        "final_det_error_mm": float(det),
        "cli_command_time_s": summary["command_time_s"] + shift,
        "state_hash": state_hash(run_dir),
        "training_hash": state_hash(run_dir, training_only=True),
    }
    for mm in THRESHOLDS_MM:
        hit = summary["time_to_accuracy"].get(f"{mm:g}mm")
        out[f"to_{mm:g}mm_s"] = hit["time_s"] + shift if hit else None
        out[f"to_{mm:g}mm_env_steps"] = hit["env_steps"] if hit else None
    return out


def state_hash(run_dir: Path, training_only: bool = False) -> str | None:
    """sha256 (16 hex digits) of every array of the newest checkpoint: names, dtypes,
    shapes and bytes; the JSON metadata left out. None without a checkpoint. With
    `training_only`, the env state's metrics left out too (the last step's reported
    errors, which nothing in training reads: a change of how XLA fuses them moves their
    last bit without changing the training, benchmarks/NOTES.md section 56)."""
    found = ckpt.list_checkpoints(run_dir)
    if not found:
        return None
    arrays, _ = ckpt.load_checkpoint(found[-1])
    h = hashlib.sha256()
    for name in sorted(arrays):
        if training_only and name.startswith("env_state/") and "/metrics/" in name:
            continue
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]
