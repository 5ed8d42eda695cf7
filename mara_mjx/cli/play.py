"""Watch a policy: python -m mara_mjx.play CHECKPOINT

    python -m mara_mjx.play runs/MARA-20250101-120000          # the MuJoCo viewer (desktop)
    python -m mara_mjx.play RUN -r                             # real-speed driver (servos)
    python -m mara_mjx.play RUN -v 0.3                         # real driver at 0.3 rad/s
    python -m mara_mjx.play RUN --video out.mp4                # offscreen, no display needed
    python -m mara_mjx.play RUN --video out.gif --width 320 --height 240 --episodes 1

Runs the deterministic policy (the Gaussian mean) of a checkpoint (a file, or a run
folder: its newest checkpoint) in the env the checkpoint names, and shows the arm, its
TCP (red) and the target marker (green, with its z axis in blue):

* default: the interactive MuJoCo viewer (gym-gazebo2's `-g`), one env step per control
  period (`control_dt`, 50 ms) of wall-clock time; closing the window stops.
* `--video PATH` (.mp4 or .gif): frames rendered offscreen (EGL or OSMesa, see
  `mara_mjx.viz.render`), one per env step, at `--fps` (default 1 / control_dt: real time).
  An existing PATH is replaced only with `--overwrite`, and only if it is a video of
  that format; the file appears whole when play ends (written beside it, then renamed).
  .mp4 goes through the ffmpeg binary of imageio-ffmpeg, started without Python code
  in the child (no os.fork warning from JAX; Ctrl-C does not reach ffmpeg, so the
  frames shown so far are kept).

A step that collides puts the arm back at the reset pose (the env's rule); its frame
shows the pose it collided in (`mara_mjx.viz.render.pose_reached`), so an episode that
ends on such a step does not end on the reset pose. Progress goes to stdout as it
happens: what is being built, the compile (the policy and env step compile at the first
call: seconds on a GPU, up to minutes on a CPU), and a line per finished episode.

`-r/--real_speed` runs the `real` driver (servo dynamics) instead of the checkpoint's;
`-v/--velocity V` sets its servo speed (rad/s, in (0, 1.57]) and implies `-r`, as
gym-gazebo2's `-r`/`-v` flags did. The episodes are those of `python -m mara_mjx.evaluate`
with the same flags: episode i resets from key split(key(seed), episodes)[i] with a joint
noise of half-width `--noise` rad and stops at the first step where every axis of the
position error is within `--tolerance_mm` (5 mm, the paper's run scripts; 0 runs to the
horizon). Each episode's final per-axis error (mm, and deg for the Orient tasks) is
printed when it ends, the accuracy table at the end.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from mara_mjx.cli.common import (
    Section,
    UserError,
    add_cache_argument,
    add_checkpoint_argument,
    add_flags,
    configure_jax,
    env_overrides,
    overrides,
    run_cli,
    uses_real_driver,
)
from mara_mjx.envs.base import EnvConfig
from mara_mjx.envs.mara import is_orient_task
from mara_mjx.envs.randomize import RandomizeConfig
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import policy as policy_io
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import (
    EvalResult,
    episode_plan,
    episode_record,
    format_table,
    reached_tolerance,
)
from mara_mjx.runtime import files, runs
from mara_mjx.viz.video import VideoWriter, is_video

PROG = "mara_mjx.play"
VIDEO_FORMATS = (".mp4", ".gif")
SECTIONS = (
    Section("eval", EvalConfig),
    # The reset noise is the eval section's --noise; rewards do not change what is shown.
    Section("env", EnvConfig, exclude=("reward", "reset_noise", "randomization")),
    Section("randomization", RandomizeConfig),
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m mara_mjx.play",
        description="Watch a PPO checkpoint's deterministic policy: the MuJoCo viewer, or "
        "a video rendered offscreen (--video).",
        allow_abbrev=False,
    )
    add_checkpoint_argument(parser)
    parser.add_argument(
        "-r",
        "--real_speed",  # gym-gazebo2's spelling
        dest="env.driver",
        action="store_const",
        const="real",
        default=argparse.SUPPRESS,
        help="use the real-speed driver (velocity-limited servos and arm dynamics), "
        "like gym-gazebo2's -r (same as --driver real)",
    )
    parser.add_argument(
        "-v",
        "--velocity",
        dest="env.velocity",
        type=float,
        metavar="V",
        default=argparse.SUPPRESS,
        help="servo speed of the real driver (rad/s, in (0, 1.57], default 0.5); implies -r, "
        "like gym-gazebo2's -v",
    )
    video = parser.add_argument_group("video (offscreen, no display needed)")
    video.add_argument(
        "--video",
        metavar="PATH",
        help="write the episodes to PATH (.mp4 or .gif) instead of opening the viewer",
    )
    video.add_argument("--width", type=int, default=640, help="frame width (px, default 640)")
    video.add_argument("--height", type=int, default=480, help="frame height (px, default 480)")
    video.add_argument(
        "--fps",
        type=float,
        help="video frame rate (default 1 / control_dt: one frame per env step, real time)",
    )
    video.add_argument(
        "--camera",
        help="a model camera (front, side); default a free camera on the workspace",
    )
    video.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing --video file (only a video of the same format)",
    )
    parser.add_argument(
        "--hold",
        type=float,
        default=1.0,
        metavar="S",
        help="seconds to show each episode's final pose (default 1)",
    )
    add_flags(parser, SECTIONS)
    add_cache_argument(parser)
    return parser


# ------------------------------------------------------------------- checks


def check_video_args(args: argparse.Namespace) -> Path | None:
    """The video path (None: the viewer), after checking every video flag."""
    if not (math.isfinite(args.hold) and args.hold >= 0):
        raise UserError(f"--hold {args.hold} must be a number of seconds >= 0")
    if args.video is None:
        return None
    path = Path(args.video)
    if path.suffix.lower() not in VIDEO_FORMATS:
        raise UserError(
            f"--video {str(path)!r}: unknown extension {path.suffix or '(none)'!r}; "
            f"use one of {', '.join(VIDEO_FORMATS)}"
        )
    if path.is_dir():
        raise UserError(f"--video {str(path)!r} is a folder; give a file name ending in .mp4/.gif")
    if path.exists() or path.is_symlink():
        if not is_video(path):
            raise UserError(
                f"--video {str(path)!r} exists and is not a {path.suffix.lower()} video; "
                "refusing to replace it (give another file name)"
            )
        if not args.overwrite:
            raise UserError(
                f"--video {str(path)!r} exists; pass --overwrite to replace it, or give "
                "another file name"
            )
    for name, value, limit in (("width", args.width, 1280), ("height", args.height, 720)):
        if not 1 <= value <= limit:
            raise UserError(f"--{name} {value} must be in [1, {limit}] pixels")
    if path.suffix.lower() == ".mp4":
        if args.width % 2 or args.height % 2:
            raise UserError(
                f"--width and --height must be even for .mp4 (H.264), got "
                f"{args.width} x {args.height}"
            )
        try:
            import imageio_ffmpeg

            imageio_ffmpeg.get_ffmpeg_exe()
        except (ImportError, RuntimeError) as e:
            raise UserError(f"cannot write .mp4 (no ffmpeg: {e}); use .gif instead") from e
    if args.fps is not None and not (math.isfinite(args.fps) and args.fps > 0):
        raise UserError(f"--fps {args.fps} must be a number > 0")
    try:
        files.check_writable(path.parent)
    except OSError as e:
        raise UserError(f"cannot write the video to {str(path)!r}: {e}") from e
    return path


def env_flags(args: argparse.Namespace) -> dict[str, Any]:
    """The command line's env overrides of the checkpoint's env config; -v implies -r."""
    flags = env_overrides(args)
    if "velocity" in flags:
        if flags.get("driver", "real") != "real":
            raise UserError(
                "--velocity sets the real driver's servo speed; it cannot be used with "
                f"--driver {flags['driver']}"
            )
        flags["driver"] = "real"
    return flags


def episode_line(
    i: int, record: dict[str, Any], orientation: bool, tolerance_mm: float, n: int
) -> str:
    """'episode i+1/n: ...' (1-based, as a progress count)."""
    x, y, z = record["position_error_mm"]
    line = f"episode {i + 1}/{n}: {int(record['steps'])} steps"
    if tolerance_mm > 0:
        line += f" ({'reached' if record['reached'] else 'did not reach'} {tolerance_mm:g} mm)"
    line += f", final error x {x:.2f} y {y:.2f} z {z:.2f} mm"
    if orientation:
        rx, ry, rz = record["orientation_error_deg"]
        line += f", orientation x {rx:.2f} y {ry:.2f} z {rz:.2f} deg"
    collisions, ret = int(record["collisions"]), float(record["episode_return"])
    return line + f", collisions {collisions}, return {ret:.1f}"


# ---------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_jax(args.compilation_cache, uses_real_driver(args, args.checkpoint))
    video_path = check_video_args(args)
    path = ckpt.find_checkpoint(args.checkpoint)
    arrays, meta = ckpt.load_checkpoint(path)
    policy = policy_io.policy_from_checkpoint(arrays, meta)
    try:
        config = EvalConfig().replace(**overrides(args, "eval"))
    except ValueError as e:
        raise UserError(f"invalid episode settings: {e}") from e
    env = runs.make_env(meta, **env_flags(args))
    name = meta["env_name"]
    cfg = env.config
    print(f"checkpoint: {path}")
    print(
        f"env: {name}, driver {cfg.driver!r}"
        + (f", velocity {cfg.velocity:g} rad/s" if cfg.driver == "real" else "")
        + f", control period {cfg.control_dt:g} s, horizon {env.max_episode_steps} steps",
        flush=True,
    )

    # The renderer or the viewer before anything compiles: a machine that cannot show
    # anything fails in a second.
    from mara_mjx.viz import render

    print(
        "opening the MuJoCo viewer ..." if video_path is None else "starting offscreen GL ...",
        flush=True,
    )
    try:
        if video_path is None:
            viewer, renderer = render.Viewer(), None
        else:
            renderer = render.ArmRenderer(args.width, args.height, args.camera).open()
            viewer = None
    except (render.RenderError, ValueError) as e:
        raise UserError(str(e)) from e

    fps = args.fps if args.fps is not None else 1.0 / cfg.control_dt
    orientation = is_orient_task(env)
    writer = None
    try:
        if video_path is not None:
            writer = VideoWriter(video_path, fps, args.width, args.height, args.overwrite)
        records = run_episodes(
            env, policy, config, viewer, renderer, writer, args.hold, orientation
        )
    except KeyboardInterrupt:  # Ctrl-C: keep the video shown so far, exit as SIGINT does
        if writer is not None:
            writer.close()
            if writer.frames:
                print(f"interrupted: wrote {video_path} ({writer.frames} frames)", flush=True)
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    else:
        if writer is not None:
            writer.close()
    finally:
        if renderer is not None:
            renderer.close()
        if viewer is not None:
            viewer.close()

    if records:
        result = EvalResult(**{k: np.array([r[k] for r in records]) for k in records[0]})
        print(format_table(name, result, orientation, config))
    if len(records) < config.episodes:
        print(f"stopped after {len(records)} of {config.episodes} episodes (viewer closed)")
    if writer is not None:
        print(f"wrote {video_path} ({writer.frames} frames at {fps:g} fps)")
    return 0


def run_episodes(
    env,
    policy,
    config: EvalConfig,
    viewer,
    renderer,
    writer,
    hold: float,
    orientation: bool = False,
):
    """Play `config.episodes` episodes (evaluate's keys and stop rule); show every step
    in the viewer (paced to control_dt of wall-clock time) or write it to the video,
    printing progress and a line per finished episode. Returns one record per finished
    episode (EvalResult's fields)."""
    import jax

    from mara_mjx.viz.render import pose_reached

    params, keys = episode_plan(env, config)  # evaluate's episodes, one at a time
    reset = jax.jit(env.reset)

    from mara_mjx.ppo.evaluation import deployed_commit, deployed_policy, held_action

    # the guard, the plan and its restarts as evaluate deploys them (--collision_guard_mm,
    # --plan_steps, --plan_starts), then held commands (commit_rad)
    policy = deployed_policy(policy, config, env)
    commit = deployed_commit(policy, config)
    bounds = (env.joint_lower, env.joint_upper)

    @jax.jit
    def step(policy, state, held):
        action, q = held_action(policy, state.obs, *held, commit, bounds)
        state = env.step(state, action)
        return state, state.metrics["collided"], (action, q)

    dt = env.config.control_dt
    target = None  # the episode's: random-target tasks draw a new one at every reset

    def show(q: np.ndarray) -> np.ndarray | None:
        if viewer is not None:
            viewer.show(q, *target)
            return None
        frame = renderer.frame(q, *target)
        writer.append(frame)
        return frame

    # The reset compiles in seconds (kinematics only): the first pose is shown while
    # the policy and the step compile, which can take minutes on a CPU.
    first = reset(keys[0], params)
    target = jax.device_get((first.params.target_pos, first.params.target_quat))
    if viewer is not None:
        viewer.show(np.asarray(first.q), *target)
    print(
        "compiling the policy and the env step (the first call; up to minutes on a CPU) ...",
        flush=True,
    )
    start = time.perf_counter()
    jax.block_until_ready(step(policy, first, (first.q, first.q)))
    print(f"compiled in {time.perf_counter() - start:.1f} s", flush=True)

    records = []
    n = len(keys)
    for i, key in enumerate(keys):
        if viewer is not None and not viewer.running:
            break
        state = reset(key, params)
        target = jax.device_get((state.params.target_pos, state.params.target_quat))
        frame = show(np.asarray(state.q))
        tick = time.perf_counter()
        q0 = state.obs[: env.action_size]
        held = (q0, q0)  # (targets sent last, joints observed then): the first choice is free
        while True:
            state, collided, held = step(policy, state, held)
            q, obs, m, terminated, truncated = jax.device_get(
                (state.q, state.obs, state.metrics, state.terminated, state.truncated)
            )
            if viewer is not None:  # pace to the control period in wall-clock time
                tick = max(tick + dt, time.perf_counter())  # resync if behind
                time.sleep(max(0.0, tick - time.perf_counter()))
            # A collision put the arm back at the reset pose: show where it was.
            frame = show(pose_reached(q, obs, collided, terminated))
            reached = bool(reached_tolerance(m, config))
            if reached or terminated or truncated:
                break
            if viewer is not None and not viewer.running:
                return records
        record = jax.device_get(episode_record(state, reached))
        records.append(record)
        print(episode_line(i, record, orientation, config.tolerance_mm, n), flush=True)
        if viewer is not None:
            time.sleep(hold)
        else:
            for _ in range(int(round(hold * writer.fps))):
                writer.append(frame)
    return records


if __name__ == "__main__":
    from mara_mjx.runtime import supervise

    sys.exit(supervise.run(lambda: run_cli(main, PROG), PROG))
