"""Watching policies: offscreen frames (`render_mode="rgb_array"`, `mara_mjx.render`), the
play CLI writing a video from a tiny checkpoint, and its clear errors on bad input
(before anything is compiled).

Rendering needs an offscreen OpenGL backend (EGL or OSMesa); where neither works the
rendering tests are skipped with the reason, the others still run. The checkpoint holds
random (untrained) weights, saved with the metadata the training CLI writes. Only the
CLI run compiles the env step (in its own process); the frame tests use resets, which
run kinematics only.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.passive_env_checker import env_render_passive_checker
from PIL import Image

import mara_mjx
from mara_mjx import play, render
from mara_mjx.cli import run_cli
from mara_mjx.gym import MaraGymEnv, gym_id
from mara_mjx.gym_vector import MaraVectorEnv
from mara_mjx.ppo import PPOConfig, RunningStats
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.networks import make_network

REPO = Path(__file__).resolve().parents[1]
W, H = 64, 48

# ffmpeg and the CLI run in child processes: fork + exec, which JAX's fork warning is
# not about.
pytestmark = pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")


@pytest.fixture(scope="module")
def gl() -> str:
    """The offscreen GL backend; skips the test where none renders."""
    try:
        with render.ArmRenderer(8, 8) as renderer:
            renderer.open()
            return render.gl_backend()
    except render.RenderError as e:
        pytest.skip(f"no offscreen OpenGL backend on this machine: {e}")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A run folder with one MARA checkpoint of random weights (normalised observations)."""
    folder = tmp_path_factory.mktemp("play") / "run"
    env = mara_mjx.make("MARA")
    config = PPOConfig(hidden_sizes=(16, 16))
    network = make_network(config, env.action_size)
    obs = jax.ShapeDtypeStruct((env.observation_size,), jnp.float32)
    shapes = jax.eval_shape(network.init, jax.random.key(0), obs, obs)  # as checkpoint.py
    # Weights of order 1 (not the 0.01-gain head) so that the arm moves; numpy, so that
    # nothing compiles here.
    rng = np.random.default_rng(0)
    params = jax.tree.map(lambda x: 0.3 * rng.standard_normal(x.shape, np.float32), shapes)
    state = {"params": params, "obs_stats": RunningStats.create(env.observation_size)}
    meta = {
        "env_name": "MARA",
        "env_config": env.config.to_dict(),
        "observation_size": env.observation_size,
        "action_size": env.action_size,
        "ppo": config.to_dict(),
        "run": {},
        "eval": {},
        "progress": {"update": 1, "env_steps": 1},
    }
    ckpt.save_checkpoint(folder / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(1), state, meta)
    return folder


@pytest.fixture(scope="module")
def rgb_env(gl) -> MaraGymEnv:
    env = MaraGymEnv("MARA", render_mode="rgb_array", width=W, height=H, reset_noise=0.5)
    yield env
    env.close()


# ------------------------------------------------------------------ frames


def test_rgb_array_frames_follow_the_pose_and_the_target(rgb_env):
    env = rgb_env
    assert env.metadata["render_fps"] == pytest.approx(20.0)  # 1 / control_dt
    with pytest.raises(gymnasium.error.ResetNeeded):
        MaraGymEnv("MARA", render_mode="rgb_array", width=W, height=H).render()

    env.reset(seed=0)
    frame = env_render_passive_checker(env)  # gymnasium's own checks of render()
    assert frame.shape == (H, W, 3) and frame.dtype == np.uint8
    assert frame.std() > 10  # a picture, not a blank buffer
    np.testing.assert_array_equal(env.render(), frame)  # same pose, same pixels

    env.reset(seed=1)  # reset noise 0.5 rad: another pose
    other = env.render()
    assert np.any(env.state.q != 0)
    changed = np.any(other != frame, axis=-1).mean()
    assert changed > 0.02, changed

    env.reset(seed=0)
    np.testing.assert_array_equal(env.render(), frame)
    target = np.array(mara_mjx.envs.base.DEFAULT_TARGET_POS) + [0.0, -0.3, 0.3]
    env.reset(seed=0, options={"target_pos": target})  # the episode's target is drawn
    env.render()
    marker = env._renderer.model.body("target").mocapid[0]
    np.testing.assert_allclose(env._renderer.data.mocap_pos[marker], target, atol=1e-6)
    assert env._jit_reset._cache_size() == 1


def test_no_gl_context_before_the_first_render(gl, monkeypatch):
    """stable-baselines3's make_vec_env builds every env with render_mode="rgb_array";
    a GL context made current at construction crashed the process when torch then
    imported triton (issue 34, item 13). The context comes at the first render()."""
    made = []
    real = render._gl_context
    monkeypatch.setattr(render, "_gl_context", lambda *a: made.append(a) or real(*a))
    monkeypatch.setattr(render, "_probe", lambda name: made.append(("probe", name)))
    envs = [
        gymnasium.make(gym_id("MARA"), render_mode="rgb_array", width=W, height=H) for _ in range(2)
    ]
    for i, env in enumerate(envs):
        env.reset(seed=i)
    assert made == [] and not envs[0].unwrapped._renderer.is_open
    frame = envs[0].render()
    assert frame.shape == (H, W, 3) and frame.std() > 10
    assert len(made) == 1 and envs[0].unwrapped._renderer.is_open
    assert not envs[1].unwrapped._renderer.is_open
    envs[0].close()
    np.testing.assert_array_equal(envs[0].render(), frame)  # a new renderer after close
    for env in envs:
        env.close()
    with render.ArmRenderer(W, H) as renderer:
        assert not renderer.is_open
    with pytest.raises(RuntimeError, match="after close"):
        renderer.open()


def test_renderer_frames_and_video_files(rgb_env, tmp_path):
    """ArmRenderer on its own (a model camera), and both video formats of the CLI's
    writer, read back."""
    with render.ArmRenderer(W, H, camera="side") as renderer:
        up = renderer.frame(np.zeros(6))
        bent = renderer.frame(np.array([0.0, 1.2, -1.0, 0.0, 0.8, 0.0]))
    assert up.shape == (H, W, 3) and np.any(up != bent)
    # The 1 cm target marker needs more pixels than W x H to be seen.
    with render.ArmRenderer(320, 240) as renderer:
        target = np.array(mara_mjx.envs.base.DEFAULT_TARGET_POS)
        here = renderer.frame(np.zeros(6), target)
        there = renderer.frame(np.zeros(6), target + [0.0, -0.3, 0.3])
    moved = np.any(here != there, axis=-1).mean()
    assert 0 < moved < 0.01, moved  # a few pixels: only the marker moved
    with pytest.raises(RuntimeError, match="after close"):
        renderer.frame(np.zeros(6))
    with pytest.raises(ValueError, match=r"camera 'top' .* \['front', 'side'\]"):
        render.ArmRenderer(W, H, camera="top")
    with pytest.raises(ValueError, match=r"width=2000 must be an int in \[1, 1280\]"):
        render.ArmRenderer(2000, H)

    frames = [up, bent, up]
    mp4 = tmp_path / "clip.mp4"
    writer = play.VideoWriter(mp4, fps=20.0, width=W, height=H)
    for f in frames:
        writer.append(f)
    writer.close()
    import imageio_ffmpeg

    assert imageio_ffmpeg.count_frames_and_secs(str(mp4)) == (3, 0.15)
    reader = imageio_ffmpeg.read_frames(str(mp4))
    assert next(reader)["size"] == (W, H)
    first = np.frombuffer(next(reader), np.uint8).reshape(H, W, 3)
    assert np.abs(first.astype(int) - up).mean() < 12  # H.264 is lossy

    gif = tmp_path / "clip.gif"
    writer = play.VideoWriter(gif, fps=20.0, width=W, height=H)
    for f in frames:
        writer.append(f)
    writer.close()
    durations = gif_durations(gif)
    assert sum(durations) == 150 and len(durations) == 3


def gif_durations(path: Path) -> list[int]:
    """Per-frame delays (ms). Pillow merges identical consecutive frames into one with the
    summed delay, so the total, not the count, measures the video's length."""
    with Image.open(path) as im:
        assert im.size == (W, H)
        durations = []
        for i in range(im.n_frames):
            im.seek(i)
            durations.append(im.info["duration"])
    return durations


# ------------------------------------------------------------------ the CLI


def test_play_writes_a_video_as_a_user_runs_it(gl, run_dir, tmp_path):
    out = tmp_path / "videos" / "play.gif"  # the folder is created
    args = [
        str(run_dir),
        "--video", str(out),
        "--width", str(W),
        "--height", str(H),
        "--episodes", "2",
        "--max_episode_steps", "3",
        "--hold", "0.1",
    ]  # fmt: skip
    proc = subprocess.run(
        [sys.executable, "-m", "mara_mjx.play", *args],
        cwd=REPO,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "driver 'train'" in proc.stdout and "horizon 3 steps" in proc.stdout
    # Per episode: the reset frame, 3 steps, then 2 frames (0.1 s at 20 fps) of hold.
    assert f"wrote {out} (12 frames at 20 fps)" in proc.stdout
    assert sum(gif_durations(out)) == 12 * 50
    lines = [line for line in proc.stdout.splitlines() if line.startswith("episode ")]
    assert [line.split(":")[0] for line in lines] == ["episode 0", "episode 1"]
    for line in lines:
        assert "3 steps" in line and "final error x " in line, line
        errors = line.split("final error x ")[1].split(" mm")[0].replace("y ", "").replace("z ", "")
        assert all(np.isfinite(float(v)) for v in errors.split())
    assert "| MARA (this policy) |" in proc.stdout


def test_bad_play_input_fails_fast_with_a_clear_message(
    run_dir, tmp_path, capsys, monkeypatch, compiled
):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"PK\x03\x04 truncated zip")
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    run = str(run_dir)
    gif = str(tmp_path / "out.gif")
    cases = [
        ([str(tmp_path / "missing.npz"), "--video", gif], "does not exist"),
        ([str(garbage), "--video", gif], "corrupt"),
        ([run, "--video", str(tmp_path / "out.avi")], "unknown extension '.avi'; use one of .mp4"),
        ([run, "--video", str(a_file / "out.gif")], "cannot write the video"),
        ([run, "--video", str(tmp_path / "o.mp4"), "--width", "65"], "must be even for .mp4"),
        ([run, "--video", gif, "--height", "721"], "--height 721 must be in [1, 720]"),
        ([run, "--video", gif, "--fps", "0"], "--fps 0.0 must be a number > 0"),
        ([run, "--video", gif, "-v", "3"], "servo speed must be in (0, 1.57]"),
        ([run, "--video", gif, "-v", "0.3", "--driver", "train"], "cannot be used with --driver"),
        ([run, "--video", gif, "--episodes", "0"], "episodes"),
        ([run, "--video", gif, "--camera", "top"], "camera 'top' is not in the model"),
        ([run], "no display for the MuJoCo viewer"),  # DISPLAY unset below
    ]
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    for argv, message in cases:
        compiled.clear()
        code = run_cli(play.main, play.PROG, argv)
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        assert message in err and err.startswith("mara_mjx.play: error:"), (argv, err)
        assert "Traceback" not in err
        ours = [n for n in compiled if "lambda" in n or "reset" in n or "step" in n]
        assert not ours, (argv, ours)
    assert not (tmp_path / "out.gif").exists()


def test_render_modes_and_missing_backends(monkeypatch):
    with pytest.raises(ValueError, match=r"render_mode='ansi' .* None, 'rgb_array', 'human'"):
        MaraGymEnv("MARA", render_mode="ansi")
    with pytest.raises(ValueError, match="MaraVectorEnv .* use None"):
        MaraVectorEnv("MARA", num_envs=2, render_mode="rgb_array")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(render.RenderError, match="no display"):
        gymnasium.make(gym_id("MARA"), render_mode="human")

    # Backend choice: a user's MUJOCO_GL is kept; otherwise EGL, then OSMesa, then a clear
    # error naming both (the probe, a child process, is replaced here).
    monkeypatch.setattr(render, "_chosen", None)
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    assert render.gl_backend() == "osmesa"
    monkeypatch.setattr(render, "_chosen", None)
    monkeypatch.delenv("MUJOCO_GL")
    failures = {"egl": "Cannot initialize a EGL device display", "osmesa": "no libOSMesa"}
    monkeypatch.setattr(render, "_probe", lambda name: failures[name])
    with pytest.raises(render.RenderError, match="MUJOCO_GL=egl: Cannot .* MUJOCO_GL=osmesa"):
        render.gl_backend()
    failures["osmesa"] = None
    assert render.gl_backend() == "osmesa" and os.environ["MUJOCO_GL"] == "osmesa"
