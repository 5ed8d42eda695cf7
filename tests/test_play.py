"""Watching policies: offscreen frames (`render_mode="rgb_array"`, `mara_mjx.viz.render`), the
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
import warnings
from pathlib import Path

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.passive_env_checker import env_render_passive_checker
from PIL import Image

import mara_mjx
from mara_mjx.adapters.gym import MaraGymEnv, gym_id
from mara_mjx.adapters.gym_vector import MaraVectorEnv
from mara_mjx.cli import play
from mara_mjx.cli.common import UserError, run_cli
from mara_mjx.ppo import PPOConfig, RunningStats
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.networks import make_network
from mara_mjx.viz import render, video

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


def test_no_gl_context_before_the_first_render(gl, monkeypatch, tmp_path):
    """stable-baselines3's make_vec_env builds every env with render_mode="rgb_array";
    a GL context made current at construction crashed the process when torch then
    imported triton (issue 34, item 13). The context comes at the first render(), and
    an installed triton is imported before it (a stand-in package here)."""
    made = []
    real = render._gl_context

    def gl_context(*args):
        made.append(args)
        assert "triton" in sys.modules  # imported before the first context
        return real(*args)

    monkeypatch.setattr(render, "_gl_context", gl_context)
    if "triton" not in sys.modules:
        (tmp_path / "triton").mkdir()
        (tmp_path / "triton" / "__init__.py").write_text("")
        monkeypatch.syspath_prepend(str(tmp_path))
        monkeypatch.setitem(sys.modules, "triton", None)  # restored (removed) afterwards
        del sys.modules["triton"]
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
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        writer = video.VideoWriter(mp4, fps=20.0, width=W, height=H)
        for f in frames:
            writer.append(f)
        assert not mp4.exists()  # written beside it until close
        writer.close()
    # imageio-ffmpeg's preexec_fn made Python fork with its at-fork hooks: JAX's
    # "os.fork() was called ... JAX is multithreaded ... deadlock" warning
    assert not [w for w in caught if "fork" in str(w.message)], [str(w.message) for w in caught]
    import imageio_ffmpeg

    assert imageio_ffmpeg.count_frames_and_secs(str(mp4)) == (3, 0.15)
    reader = imageio_ffmpeg.read_frames(str(mp4))
    assert next(reader)["size"] == (W, H)
    first = np.frombuffer(next(reader), np.uint8).reshape(H, W, 3)
    assert np.abs(first.astype(int) - up).mean() < 12  # H.264 is lossy

    gif = tmp_path / "clip.gif"
    writer = video.VideoWriter(gif, fps=20.0, width=W, height=H)
    for f in frames:
        writer.append(f)
    writer.close()
    durations = gif_durations(gif)
    assert sum(durations) == 150 and len(durations) == 3

    # A file that appears at the path while playing is kept (the video is not written)
    # unless --overwrite; an aborted video leaves nothing.
    for suffix in (".mp4", ".gif"):
        path = tmp_path / f"taken{suffix}"
        writer = video.VideoWriter(path, fps=20.0, width=W, height=H)
        writer.append(up)
        path.write_text("someone else's")
        with pytest.raises(UserError, match="appeared while playing"):
            writer.close()
        assert path.read_text() == "someone else's"
        writer = video.VideoWriter(path, fps=20.0, width=W, height=H, overwrite=True)
        writer.append(up)
        writer.close()
        assert video.is_video(path)
        writer = video.VideoWriter(tmp_path / f"aborted{suffix}", fps=20.0, width=W, height=H)
        writer.append(up)
        writer.abort()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "clip.gif", "clip.mp4", "taken.gif", "taken.mp4"
    ]  # fmt: skip


def test_an_episode_that_ends_on_a_collision_ends_on_the_pose_it_collided_in(rgb_env):
    """A colliding step puts the arm back at the reset pose; its frame (the last of an
    episode that ends there, held for --hold) showed that reset pose (issue 34, item 16).
    Frames show the pose the step reached, in play and in `render()`."""
    env = mara_mjx.make("MARA", max_episode_steps=2)
    fold = np.array([0.0, 2.0, 0.0, 0.0, 0.0, 0.0], np.float32)  # the shoulder into the table
    shown, written = [], []

    class Renderer:
        def frame(self, q, target_pos, target_quat):
            shown.append(np.asarray(q))
            return np.full((1, 1, 3), len(shown), np.uint8)

    class Writer:
        fps = 20.0

        def append(self, frame):
            written.append(int(frame[0, 0, 0]))

    policy = jax.tree_util.Partial(lambda obs: jnp.asarray(fold))
    config = EvalConfig(episodes=1, noise=0.0)
    records = play.run_episodes(env, policy, config, None, Renderer(), Writer(), hold=0.1)
    assert records[0]["collisions"] == 2  # both steps fold into the table
    np.testing.assert_array_equal(shown[0], np.zeros(6))  # the reset
    for q in shown[1:]:
        np.testing.assert_allclose(q, fold)  # not the reset pose the env put it back at
    assert written == [1, 2, 3, 3, 3]  # the last frame held for 0.1 s at 20 fps

    # render(): the same rule, on a state whose step collided (q back at the reset pose)
    rgb_env.reset(seed=0)
    state = rgb_env.state
    with render.ArmRenderer(W, H) as renderer:
        target = jax.device_get((state.params.target_pos, state.params.target_quat))
        want = renderer.frame(fold, *target)
    rgb_env.state = state.replace(
        q=jnp.zeros(6),
        obs=state.obs.at[:6].set(fold),
        metrics={**state.metrics, "collided": jnp.float32(1.0)},
    )
    np.testing.assert_array_equal(rgb_env.render(), want)


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
    out = tmp_path / "videos" / "play.mp4"  # the folder is created
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
    # ffmpeg is started without a preexec_fn: no fork with Python at-fork hooks (JAX's
    # warning), and no other noise (mujoco.mjx's "Failed to import warp")
    assert "os.fork" not in proc.stderr and "Failed to import" not in proc.stdout, proc.stderr
    assert "driver 'train'" in proc.stdout and "horizon 3 steps" in proc.stdout
    # Progress as it happens: the compile, then a line per episode before the table.
    lines = proc.stdout.splitlines()
    compiling = next(i for i, line in enumerate(lines) if line.startswith("compiling the policy"))
    assert lines[compiling + 1].startswith("compiled in ")
    episodes = [i for i, line in enumerate(lines) if line.startswith("episode ")]
    assert [lines[i].split(":")[0] for i in episodes] == ["episode 1/2", "episode 2/2"]
    table = next(i for i, line in enumerate(lines) if "| MARA (this policy) |" in line)
    assert compiling < episodes[0] < episodes[1] < table
    for i in episodes:
        assert "3 steps" in lines[i] and "final error x " in lines[i], lines[i]
        errors = lines[i].split("final error x ")[1].split(" mm")[0]
        assert all(
            np.isfinite(float(v)) for v in errors.replace("y ", "").replace("z ", "").split()
        )
    # Per episode: the reset frame, 3 steps, then 2 frames (0.1 s at 20 fps) of hold.
    assert f"wrote {out} (12 frames at 20 fps)" in proc.stdout
    import imageio_ffmpeg

    assert imageio_ffmpeg.count_frames_and_secs(str(out)) == (12, 0.6)
    assert sorted(p.name for p in out.parent.iterdir()) == ["play.mp4"]  # no temporary left


def test_bad_play_input_fails_fast_with_a_clear_message(
    run_dir, tmp_path, capsys, monkeypatch, compiled
):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"PK\x03\x04 truncated zip")
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    not_a_video = tmp_path / "notes.mp4"
    not_a_video.write_text("my notes")
    a_gif = tmp_path / "old.gif"
    Image.new("RGB", (4, 4)).save(a_gif)
    before = {p: p.read_bytes() for p in (not_a_video, a_gif)}
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
        # never a file play did not write: a foreign file even with --overwrite, a video
        # only with it
        ([run, "--video", str(not_a_video), "--overwrite"], "is not a .mp4 video; refusing"),
        ([run, "--video", str(a_gif)], "exists; pass --overwrite to replace it"),
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
    assert {p: p.read_bytes() for p in before} == before


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


def test_ctrl_c_keeps_the_video_shown_so_far(run_dir, tmp_path, monkeypatch, capsys):
    """Ctrl-C while playing: the frames so far are written (ffmpeg, in a process group of
    its own, does not get the signal), no temporary file is left, exit status 130."""
    frames = []

    class Renderer:  # the 5th frame is where the user presses Ctrl-C
        def __init__(self, *args):
            pass

        def open(self):
            return self

        def frame(self, q, target_pos, target_quat):
            if len(frames) == 4:
                raise KeyboardInterrupt
            frames.append(q)
            return np.full((H, W, 3), 40 * len(frames), np.uint8)

        def close(self):
            pass

    monkeypatch.setattr(render, "ArmRenderer", Renderer)
    out = tmp_path / "stopped.mp4"
    argv = [str(run_dir), "--video", str(out), "--width", str(W), "--height", str(H)]
    code = run_cli(play.main, play.PROG, [*argv, "--max_episode_steps", "3", "--hold", "0"])
    captured = capsys.readouterr()
    assert code == 130 and "interrupted" in captured.err, captured.err
    assert f"interrupted: wrote {out} (4 frames)" in captured.out
    import imageio_ffmpeg

    assert imageio_ffmpeg.count_frames_and_secs(str(out))[0] == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stopped.mp4"]


def test_play_deploys_the_plan_and_guard_overrides_as_evaluate_does(tmp_path, monkeypatch):
    """`play RUN --plan_steps 0` (a planned checkpoint, orient_first's restarts) plays the
    policy's own step, as `evaluate --plan_steps 0` judges it; `--plan_steps K` plans; a
    plan at another control period is refused as evaluate refuses it."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_export_plots import make_run

    from mara_mjx.ppo import policy as policy_module
    from mara_mjx.ppo.policy import make_policy

    run = make_run(tmp_path / "run", "MARA", True, relative=True, plan_steps=2, plan_starts=1)
    policy = make_policy(str(run))
    env = mara_mjx.make("MARA", max_episode_steps=2)
    calls = []
    real = policy_module.planned_landing
    monkeypatch.setattr(policy_module, "planned_landing", lambda *a: calls.append(1) or real(*a))

    class Writer:
        fps = 20.0

        def append(self, frame):
            pass

    class Renderer:
        def frame(self, q, target_pos, target_quat):
            return np.zeros((1, 1, 3), np.uint8)

    def play_with(**overrides):
        calls.clear()
        config = EvalConfig(episodes=1, noise=0.0, **overrides)
        play.run_episodes(env, policy, config, None, Renderer(), Writer(), hold=0.0)
        return bool(calls)

    assert not play_with(plan_steps=0)  # off: the policy's own step, no landing imagined
    assert play_with()  # as trained: the checkpoint's plan
    slow = mara_mjx.make("MARA", max_episode_steps=2, control_dt=0.1)
    with pytest.raises(ValueError, match="plan"):
        play.run_episodes(slow, policy, EvalConfig(episodes=1, noise=0.0), None, Renderer(),
                          Writer(), hold=0.0)  # fmt: skip
