"""Export a trained policy for use outside JAX: one .npz file, a pure-numpy policy, or
an ONNX model (the suffix chooses).

    python -m mara_mjx.export runs/MARA-.../ OUT.npz        # newest checkpoint of a run
    python -m mara_mjx.export runs/MARA-.../checkpoints/ckpt_00000100.npz OUT.npz
    python -m mara_mjx.export runs/MARA-.../ OUT.onnx       # ONNX (pip install ".[export]")
    python -m mara_mjx.export runs/MARA-.../ OUT.onnx --batch 1   # one arm per call, faster

    from mara_mjx.cli.export import load_exported   # mara_mjx.deploy.numpy_policy's
    policy = load_exported("OUT.npz")
    action = policy(obs)          # (obs_size,) or (N, obs_size) -> (..., 6) rad, numpy only

`policy(obs)` computes what `mara_mjx.ppo.make_policy` computes (the deterministic
Gaussian mean), in numpy: `NumpyPolicy` of mara_mjx/deploy/numpy_policy.py, whose module
docstring states the computation (quaternion sign, observation normaliser, hidden
observations, the tanh MLP, max_joint_step, relative actions and, for a policy with an
IK finish (PolicyConfig.ik_finish; format mara_mjx.export/2, meta "ik_finish"), the IK
step near the target, mara_mjx/deploy/ik_numpy.py). The action is an absolute joint
target (rad) for motor1..motor6; the env clips it to the joint limits (`policy(obs,
clip=True)` does the same here). The .onnx file: input "obs" (N, obs_size)
float32, outputs "action" and "action_clipped" (N, 6) rad; a joint-space policy's graph is
written node by node (`mara_mjx/deploy/onnx_policy.py`, needs onnx), a policy with IK rules
(ik_prior, task_space_actions, ik_finish, collision_guard_mm) is traced from the JAX
policy by jax2onnx, all its rules in the graph and checked against JAX before it is written
(`mara_mjx/deploy/onnx_graph.py`, needs the [export] extra; meta "rules_in_graph"). .npz
refuses ik_prior, task_space_actions and collision_guard_mm policies (numpy has no
Jacobian and no contact distances).

File layout (`np.load(path)`; no pickles):
    layer_<i>/kernel   (in, out) float32, i = 0 .. len(hidden_sizes)   y = x @ kernel + bias
    layer_<i>/bias     (out,) float32
    obs_mean, obs_var  (obs_size,) float32, only when the run normalised observations
    __meta__           JSON: format, env_name, env_config, observation_size, action_size,
                       hidden_sizes, activation, normalize_obs, obs_clip, obs_var_eps,
                       relative_actions (add obs[..., :action_size] to the MLP output),
                       max_joint_step (> 0: the MLP output d becomes m tanh(d / m) first),
                       ik_finish (the IK finish of PolicyConfig.ik_finish: its radius, the
                       arm's chain and task_space's constants; mara_mjx/deploy/ik_numpy.py runs
                       it on the MLP's joint displacement before q is added),
                       ik_finish_dropped (m; > 0: the checkpoint's IK finish within that
                       distance of the target is not in this file: --drop_ik_finish),
                       hidden_obs (indices set to 0 after normalisation),
                       quat_index (-1, or where the sign-canonicalised quaternion starts),
                       observation_layout [{name, start, stop, units, description}],
                       action {joint_names, lower, upper, units, description},
                       source {checkpoint, update, env_steps},
                       control_dt (s, the control period), commit_rad (rad; > 0: hold
                       each command until the arm arrives or stops, PolicyConfig.commit_rad:
                       the runner applies it, deploy/numpy_policy.committed),
                       recipe {preset, config}

The output is written atomically and never replaces a checkpoint (any file of a
`checkpoints/` folder, or a mara_mjx checkpoint anywhere) or a run folder's own file; an
existing file only if it is an exported policy (exporting again replaces it), or with
`--overwrite` (`mara_mjx.runtime.outputs.check_output`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

# the exported file's reader, numpy only (the robot-side runner's too)
from mara_mjx.deploy.numpy_policy import (
    FORMAT,
    FORMAT_FINISH,
    FORMATS,
    OBS_VAR_EPS,
    SUFFIXES,
    ExportError,
    NumpyPolicy,  # noqa: F401  (re-exported: mara_mjx.cli.export.NumpyPolicy)
    from_arrays,
    load_exported,
)
from mara_mjx.runtime import files
from mara_mjx.runtime.npzmeta import META_KEY, NPZ_ERRORS, read_npz_with_meta

PROG = "python -m mara_mjx.export"


def export_policy(
    checkpoint: str | os.PathLike,
    out_path: str | os.PathLike,
    drop_ik_finish: bool = False,
    overwrite: bool = False,
    batch: int | None = None,
    plan_steps: int | None = None,
    commit_rad: float | None = None,
    plan_starts: int | None = None,
) -> Path:
    """Write the deterministic policy of `checkpoint` (a checkpoint file, or a run folder:
    its newest checkpoint) to `out_path`, atomically: .npz (numpy) or .onnx (an ONNX
    model, needs the `onnx` package; with IK rules, jax2onnx: module docstring; `batch`: a
    static batch size for a traced graph, None for any). A policy with an IK finish
    (PolicyConfig.ik_finish) keeps it (.npz: the arm's chain in the meta's ik_finish, run
    by mara_mjx/deploy/ik_numpy.py; .onnx: in the graph) unless `drop_ik_finish`, which
    writes the learnt policy alone (the meta's ik_finish_dropped says so). An
    existing `out_path` is replaced only if it is an exported policy, or with
    `overwrite`; never a checkpoint or a run folder's file (module docstring).
    `plan_steps`: the deployed policy's imagined train-driver steps
    (PolicyConfig.plan_steps, deployed only; None: as trained; 0: off). `commit_rad`:
    the held commands' arrival tolerance (PolicyConfig.commit_rad; None: as trained; 0:
    off), written in the metadata (its "commit_rad") for the runner to apply.
    `plan_starts`: the plan's other starting postures (PolicyConfig.plan_starts; None: as
    trained; 0: off; 0 too where plan_steps is set to 0). Raises
    ExportError (or mara_mjx.ppo.CheckpointError, also a ValueError) with what is
    wrong."""
    import mara_mjx
    from mara_mjx.envs.arm import JOINTS
    from mara_mjx.ppo import checkpoint as ckpt
    from mara_mjx.ppo import policy as policy_io
    from mara_mjx.ppo.parametrisation import PLAN_START_STEPS, check_plan_period, plan_overrides
    from mara_mjx.runtime import outputs, runs

    out_path = Path(out_path)
    if out_path.suffix not in SUFFIXES:
        raise ExportError(f"output {str(out_path)!r} must end in .npz or .onnx")
    if out_path.suffix == ".onnx":
        try:
            import onnx  # noqa: F401
        except ImportError as e:
            raise ExportError(
                "writing .onnx needs the onnx package: pip install 'mara_mjx[onnx]' "
                "(or pip install onnx)"
            ) from e
    from mara_mjx.cli.common import UserError

    try:
        outputs.check_output(out_path, "export output", is_exported, overwrite)
    except UserError as e:
        raise ExportError(str(e)) from e
    source = ckpt.find_checkpoint(checkpoint)
    arrays, meta = ckpt.load_checkpoint(source)
    policy = policy_io.policy_from_checkpoint(arrays, meta)
    plan = plan_overrides(plan_steps, plan_starts)
    if plan:
        try:
            policy = policy.replace(config=policy.config.replace(**plan))
        except ValueError as e:
            raise ExportError(
                f"--{'plan_starts' if plan_starts is not None else 'plan_steps'}: {e}"
            ) from e
    if commit_rad is not None:
        try:
            policy = policy.replace(config=policy.config.replace(commit_rad=float(commit_rad)))
        except ValueError as e:
            raise ExportError(f"--commit_rad: {e}") from e
    config, ppo = policy.config.policy, policy.config.ppo
    # options whose actions need the arm's Jacobian or its contact distances, which the
    # numpy MLP does not have
    options = {
        "ik_prior": config.ik_prior,
        "task_space_actions": config.task_space_actions,
        "collision_guard_mm": config.collision_guard_mm,
        "plan_steps": config.plan_steps,
        "plan_starts": config.plan_starts,
    }
    jacobian = [(k, v) for k, v in options.items() if v]
    if jacobian and out_path.suffix == ".npz":
        option, value = jacobian[0]
        raise ExportError(
            f"the policy of {str(source)!r} has {option}={value!r}, which needs the arm's "
            "Jacobian or contact distances (mara_mjx.envs.task_space, envs/clearance); .npz "
            "export supports joint-space policies "
            "only. Export .onnx (its graph runs every rule; pip install 'mara_mjx[export]'), "
            "train with --preset default for a joint-space policy, or use "
            "mara_mjx.ppo.load_policy(checkpoint) in JAX"
        )
    finish = float(config.ik_finish)
    keep_finish = finish > 0.0 and not drop_ik_finish
    if finish > 0.0 and not keep_finish:  # the learnt policy alone, in either format
        policy = policy.replace(config=policy.config.replace(ik_finish=0.0))
    in_graph = out_path.suffix == ".onnx" and bool(jacobian or keep_finish)

    env_name, env_config = meta["env_name"], meta["env_config"]
    try:
        overrides = {**runs.env_overrides(env_config), "check_target": False}
        env = mara_mjx.make(env_name, **overrides)
    except (ValueError, TypeError) as e:
        raise ExportError(
            f"cannot rebuild env {env_name!r} of the checkpoint (needed for the observation "
            f"layout and the joint limits): {e}"
        ) from e
    try:
        check_plan_period(config.plan_steps, env)
    except ValueError as e:
        raise ExportError(str(e)) from e
    if env.observation_size != meta["observation_size"]:
        raise ExportError(
            f"env {env_name!r} has observation size {env.observation_size}, but the checkpoint "
            f"was trained on {meta['observation_size']}"
        )
    out: dict[str, np.ndarray] = {}
    actor = policy.params["params"]["actor"]
    n_layers = len(ppo.hidden_sizes) + 1
    for i in range(n_layers):
        layer = actor[f"Dense_{i}"]
        out[f"layer_{i}/kernel"] = np.asarray(layer["kernel"], np.float32)
        out[f"layer_{i}/bias"] = np.asarray(layer["bias"], np.float32)
    if policy.obs_stats is not None:
        out["obs_mean"] = np.asarray(policy.obs_stats.mean, np.float32)
        out["obs_var"] = np.asarray(policy.obs_stats.var, np.float32)
    progress = meta.get("progress", {})
    export_meta = {
        "format": FORMAT_FINISH if keep_finish and not in_graph else FORMAT,
        "env_name": env_name,
        "env_config": env_config,
        "observation_size": int(meta["observation_size"]),
        "action_size": int(meta["action_size"]),
        "hidden_sizes": list(ppo.hidden_sizes),
        "activation": "tanh",
        "normalize_obs": policy.obs_stats is not None,
        "obs_clip": float(ppo.obs_clip),
        "obs_var_eps": OBS_VAR_EPS,
        "relative_actions": bool(config.relative_actions),
        "max_joint_step": float(getattr(config, "max_joint_step", 0.0)),
        "ik_finish_dropped": 0.0 if keep_finish else finish,
        "hidden_obs": [int(i) for i in config.hidden_obs],
        "quat_index": int(config.quat_index) if config.canonical_quat else -1,
        "observation_layout": env.observation_layout,
        "action": {
            "joint_names": list(JOINTS),
            "lower": [float(x) for x in env.joint_lower],
            "upper": [float(x) for x in env.joint_upper],
            "units": "rad",
            "description": "absolute joint position targets; the env clips them to [lower, upper]",
        },
        "source": {
            "checkpoint": str(source.resolve()),
            "update": progress.get("update"),
            "env_steps": progress.get("env_steps"),
        },
        "control_dt": float(env.config.control_dt),
        "commit_rad": float(config.commit_rad),
        "recipe": {"preset": meta.get("preset", ""), "config": policy.config.to_dict()},
    }
    if in_graph:  # every rule is in the traced graph (mara_mjx/deploy/onnx_graph.py)
        from mara_mjx.deploy import onnx_graph

        export_meta["rules_in_graph"] = True
        try:
            model = onnx_graph.build_model(
                policy, env.joint_lower, env.joint_upper, export_meta, batch
            )
        except onnx_graph.OnnxGraphError as e:
            raise ExportError(f"{str(source)!r}: {e}") from e
        _write_atomic(out_path, lambda f: onnx_graph.save(model, f))
        if config.plan_steps and not config.commit_rad:  # (orient_first's: 0.16-0.8 s a call)
            print(f"note: every call of {out_path} imagines {config.plan_steps} policy steps "
                  f"(and up to {config.plan_starts} x {PLAN_START_STEPS} more where they miss); "
                  "for servos at 20 Hz export with --commit_rad 0.01, so that the runner asks "
                  "it only once the arm has arrived or stopped (docs/sim-to-real-and-"
                  "deployment.md)", file=sys.stderr)  # fmt: skip
        return out_path
    if keep_finish:  # the numpy policy runs it (mara_mjx/deploy/ik_numpy.py)
        from mara_mjx.deploy.ik_numpy import finish_meta

        export_meta["ik_finish"] = finish_meta(finish)
    out[META_KEY] = np.array(json.dumps(export_meta))
    if out_path.suffix == ".onnx":
        from mara_mjx.deploy import onnx_policy

        _write_atomic(out_path, lambda f: onnx_policy.save(from_arrays(out, export_meta), f))
    else:
        _write_atomic(out_path, lambda f: np.savez(f, **out))
    return out_path


def is_exported(path: Path) -> bool:
    """True if `path` is a policy file this module wrote (.npz or .onnx)."""
    if path.suffix == ".onnx":
        try:
            import onnx

            model = onnx.load(str(path), load_external_data=False)
        except Exception:  # not ONNX, or no onnx package: not known to be ours
            return False
        return any(p.key == "mara_mjx" for p in model.metadata_props)
    try:
        _, meta = read_npz_with_meta(path)
    except NPZ_ERRORS:
        return False
    return isinstance(meta, dict) and meta.get("format") in FORMATS


def _write_atomic(path: Path, write: Any) -> None:
    """write(binary file) to `path` atomically (runtime/files.py); ExportError if it cannot."""
    try:
        files.write_atomic(path, write)
    except OSError as e:
        raise ExportError(f"cannot write {str(path)!r}: {e}") from e


def build_parser() -> argparse.ArgumentParser:
    from mara_mjx.cli.common import add_deprecated_alias

    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="checkpoint .npz file, or a run folder (its newest)")
    parser.add_argument("out", help="output file: .npz (numpy) or .onnx (ONNX)")
    parser.add_argument(
        "--drop_ik_finish",
        action="store_true",
        help="export a policy with an IK finish (ik_finish, the position tasks' presets) "
        "without it: the learnt policy alone (both formats keep the finish otherwise)",
    )
    parser.add_argument(
        "--batch",
        type=int,
        default=None,
        help=".onnx of a policy with IK rules: a static batch size (1: one arm per call, "
        "about half the latency); default any batch",
    )
    parser.add_argument(
        "--plan_steps",
        type=int,
        default=None,
        help="the deployed policy commands the landing of this many imagined train-driver "
        "steps (PolicyConfig.plan_steps; for a servo-driven arm; 0 off); default as trained",
    )
    parser.add_argument(
        "--plan_starts",
        type=int,
        default=None,
        help="where the plan's own landing misses, the deployed policy also imagines it from "
        "this many other postures and commands a landing that reaches (PolicyConfig."
        "plan_starts; needs plan_steps; 0 off); default as trained",
    )
    parser.add_argument(
        "--commit_rad",
        type=float,
        default=None,
        help="the runner holds each command until the arm is within this many rad of it or "
        "stops (PolicyConfig.commit_rad; for a servo-driven arm; 0 off); default as trained",
    )
    add_deprecated_alias(parser, "--drop-ik-finish", "--drop_ik_finish", PROG)
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace OUT even if it is not an exported policy (never a checkpoint or a "
        "run folder's own file)",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    from mara_mjx.cli.common import UserError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.out.endswith(".onnx"):  # a graph is traced on the CPU (onnx_graph)
            import jax

            with contextlib.suppress(Exception):  # unless a backend has started already
                jax.config.update("jax_platforms", "cpu")
        out = export_policy(
            args.checkpoint,
            args.out,
            args.drop_ik_finish,
            args.overwrite,
            args.batch,
            args.plan_steps,
            args.commit_rad,
            args.plan_starts,
        )
        if out.suffix == ".onnx":
            print(f"wrote {out}: ONNX (opset 17), input obs (N, obs_size) float32, outputs "
                  "action and action_clipped (N, 6) rad")  # fmt: skip
            return 0
        policy = load_exported(out)
    except ExportError as e:
        raise UserError(str(e)) from e
    norm = "with" if policy.obs_mean is not None else "without"
    print(
        f"wrote {out}: {policy.env_name} policy, obs {policy.observation_size} -> action "
        f"{policy.action_size}, hidden {tuple(policy.meta['hidden_sizes'])}, {norm} "
        "observation normalisation"
    )
    return 0


if __name__ == "__main__":
    from mara_mjx.cli.common import run_cli
    from mara_mjx.runtime import supervise

    sys.exit(supervise.run(lambda: run_cli(main, PROG), PROG))
