"""Pictures of the MARA arm with C MuJoCo (host side): offscreen frames and the viewer.

    renderer = ArmRenderer(width=640, height=480)         # offscreen (EGL or OSMesa)
    frame = renderer.frame(q, target_pos, target_quat)    # (480, 640, 3) uint8
    renderer.close()

    viewer = Viewer()                                     # a desktop window
    viewer.show(q, target_pos, target_quat)
    viewer.close()

Both show the arm at joint positions q (6,) rad, the TCP (the red `tcp` site) and the
target marker (the green mocap body `target` with its blue z axis) at the target pose
(position (3,) m, world frame; orientation (w, x, y, z)). Nothing here touches JAX: the
pose is written into a `mujoco.MjData` of the same model (assets/mara.xml) and
`mj_forward` computes the rest.

The offscreen GL context is made at the first `frame()` (or `open()`), not when the
renderer is built: a process that never renders never has one. This matters beyond
saving the work: a GL context made current in a process that later imports triton (as
torch does when stable-baselines3 builds its PPO, and SB3's `make_vec_env` builds every
env with render_mode="rgb_array") crashes that process with a segmentation fault
(measured with Mesa's EGL, triton 3.9.0, torch 2.13.0; triton imported first, both
work). So where triton is installed and not yet imported, it is imported before the
first context (about 0.3 s): rendering before SB3's PPO exists works too.

Offscreen GL backend (`gl_backend()`): a user-set MUJOCO_GL is used as given; otherwise
EGL, then OSMesa, whichever first renders a test frame in a child process (a process
cannot switch PyOpenGL platforms once one is loaded, so the choice is tried outside
it). The choice is made once per process and written to MUJOCO_GL for child processes.
"""

from __future__ import annotations

import atexit
import importlib
import importlib.util
import os
import subprocess
import sys
import warnings

import mujoco
import numpy as np

from mara_mjx.envs.arm import load_model

OFFSCREEN_BACKENDS = ("egl", "osmesa")
"""Tried in this order when MUJOCO_GL is not set."""

# The free camera's view of the workspace: the arm (up to 1.77 m tall when straight),
# the table top around it and the default target, from the front right.
CAMERA_LOOKAT = (-0.1, 0.0, 1.15)  # m, world frame
CAMERA_DISTANCE = 2.0  # m
CAMERA_AZIMUTH = 135.0  # deg
CAMERA_ELEVATION = -15.0  # deg
# Shadow map size (px) of the offscreen renderer: MuJoCo's default 4096 costs about 0.1 s
# a frame with software GL (llvmpipe), 1024 about a third of that, and still looks right.
SHADOW_SIZE = 1024

_PROBE = """
import mujoco
m = mujoco.MjModel.from_xml_string(
    "<mujoco><worldbody><geom type='sphere' size='1'/></worldbody></mujoco>")
with mujoco.Renderer(m, 8, 8) as r:
    r.update_scene(mujoco.MjData(m))
    assert r.render().shape == (8, 8, 3)
"""

_chosen: str | None = None


class RenderError(RuntimeError):
    """Rendering is unavailable here (no GL backend, no display); the message says why
    and what to do."""


def gl_backend() -> str:
    """The offscreen GL backend of this process: MUJOCO_GL if set, else the first of
    OFFSCREEN_BACKENDS that renders. RenderError naming each one tried if none does."""
    global _chosen
    if _chosen is not None:
        return _chosen
    user = os.environ.get("MUJOCO_GL", "").strip().lower()
    if user:
        _chosen = user
        return _chosen
    failures = []
    for name in OFFSCREEN_BACKENDS:
        reason = _probe(name)
        if reason is None:
            os.environ["MUJOCO_GL"] = name
            _chosen = name
            return _chosen
        failures.append(f"MUJOCO_GL={name}: {reason}")
    raise RenderError(
        "no offscreen OpenGL backend works here (tried "
        + "; ".join(failures)
        + "). Install EGL (Debian/Ubuntu: apt install libegl1) or OSMesa "
        "(apt install libosmesa6), or set MUJOCO_GL to a backend that works "
        "(egl, osmesa, or glfw with a display)"
    )


def _probe(name: str) -> str | None:
    """None if MUJOCO_GL=name renders a test frame in a child process, else why not."""
    env = {**os.environ, "MUJOCO_GL": name}
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=60
        )
    except (OSError, subprocess.SubprocessError) as e:
        return str(e)
    if proc.returncode == 0:
        return None
    lines = [line.strip() for line in proc.stderr.splitlines() if line.strip()]
    return lines[-1] if lines else f"exit status {proc.returncode}"


def _import_triton_first() -> None:
    """Import triton, if installed and not imported yet, before a GL context exists (see
    the module docstring: the other order crashes the process)."""
    if "triton" in sys.modules or importlib.util.find_spec("triton") is None:
        return
    try:
        importlib.import_module("triton")
    except Exception:  # a broken triton install: torch will report it itself
        pass


def _gl_context(backend: str, width: int, height: int):
    """A current GL context of `backend` (mujoco's egl, osmesa, cgl or glfw module)."""
    module = backend if backend in ("egl", "osmesa", "cgl") else "glfw"
    if backend in ("disable", "disabled", "off", "false", "0"):
        raise RenderError(f"MUJOCO_GL={backend} turns MuJoCo's rendering off")
    try:
        context = importlib.import_module(f"mujoco.{module}").GLContext(width, height)
        context.make_current()
    except Exception as e:  # each backend fails its own way
        raise RenderError(
            f"cannot create an OpenGL context with MUJOCO_GL={backend}: "
            f"{type(e).__name__}: {e}. Try MUJOCO_GL=" + " or MUJOCO_GL=".join(OFFSCREEN_BACKENDS)
        ) from e
    return context


def set_pose(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    q: np.ndarray,
    target_pos: np.ndarray | None = None,
    target_quat: np.ndarray | None = None,
) -> None:
    """Write joint positions q (6,) rad and the target marker's pose into `data`, at
    rest, and run `mj_forward` (kinematics, contacts, everything a picture shows)."""
    data.qpos[:] = np.asarray(q, np.float64)
    data.qvel[:] = 0.0
    mocap = model.body_mocapid[model.body("target").id]
    if target_pos is not None:
        data.mocap_pos[mocap] = np.asarray(target_pos, np.float64)
    if target_quat is not None:
        quat = np.asarray(target_quat, np.float64)
        data.mocap_quat[mocap] = quat / np.linalg.norm(quat)
    mujoco.mj_forward(model, data)


def pose_reached(
    q: np.ndarray, obs: np.ndarray, collided: np.ndarray, terminated: np.ndarray
) -> np.ndarray:
    """The joint positions (6,) rad a step reached, for its picture: `q` (the state's),
    except where the step collided or blew up and the env put the arm back at the reset
    pose: there the pose the step's observation was taken at (its first 6 entries, the
    mara observation layout; with randomisation the encoders' reading, off by their
    offset and noise). Drawing the state's q there showed the arm snapping back to the
    reset pose in the frame that ends an episode. Works batched ((N, 6), (N, obs), (N,))."""
    q, obs = np.asarray(q), np.asarray(obs)
    back = (np.asarray(collided) > 0) | np.asarray(terminated, bool)
    return np.where(back[..., None], obs[..., : q.shape[-1]], q)


def default_camera(camera: mujoco.MjvCamera | None = None) -> mujoco.MjvCamera:
    """The free camera on the workspace (written into `camera` if given)."""
    camera = mujoco.MjvCamera() if camera is None else camera
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = CAMERA_LOOKAT
    camera.distance = CAMERA_DISTANCE
    camera.azimuth = CAMERA_AZIMUTH
    camera.elevation = CAMERA_ELEVATION
    return camera


class ArmRenderer:
    """Offscreen frames of the arm, TCP and target marker.

    Args:
      width, height: frame size in pixels, at most the model's offscreen buffer
        (1280 x 720, `<visual><global offwidth offheight>` in assets/mara.xml).
      camera: None (a free camera on the workspace) or the name of a model camera
        ("front", "side").
      model: the MjModel to draw (default: assets/mara.xml, with a SHADOW_SIZE shadow
        map).

    ValueError for a bad size or camera, here. The GL context is made at the first
    `frame()` or `open()` (RenderError there when no GL backend works, see
    `gl_backend`). Call `close()` (or use `with`) to free it.
    """

    def __init__(
        self,
        width: int = 640,
        height: int = 480,
        camera: str | None = None,
        model: mujoco.MjModel | None = None,
    ):
        if model is None:
            model = load_model()
            model.vis.quality.shadowsize = SHADOW_SIZE
        self.model = model
        max_w, max_h = self.model.vis.global_.offwidth, self.model.vis.global_.offheight
        for name, value, limit in (("width", width, max_w), ("height", height, max_h)):
            if not isinstance(value, int | np.integer) or not 1 <= value <= limit:
                raise ValueError(f"{name}={value!r} must be an int in [1, {limit}] pixels")
        self.width, self.height = int(width), int(height)
        self.camera = self._camera(camera)
        self.data = mujoco.MjData(self.model)
        self.backend: str | None = None  # the GL backend, once open
        self._gl = self._context = None
        self._closed = False
        self._scene = mujoco.MjvScene(self.model, maxgeom=1000)
        self._option = mujoco.MjvOption()
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)

    @property
    def is_open(self) -> bool:
        """True once the GL context exists (after the first `frame()` or `open()`)."""
        return self._context is not None

    def open(self) -> ArmRenderer:
        """Make the GL context now (`frame()` does at its first call); RenderError if no
        GL backend works. Idempotent. Returns self."""
        if self._closed:
            raise RuntimeError("ArmRenderer used after close()")
        if self._context is not None:
            return self
        self.backend = gl_backend()
        _import_triton_first()
        gl = _gl_context(self.backend, self.width, self.height)
        try:
            context = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_150)
        except mujoco.FatalError as e:  # e.g. glfw without a display: no GL loaded
            gl.free()
            raise RenderError(
                f"MuJoCo cannot render with MUJOCO_GL={self.backend}: {e}. Try MUJOCO_GL="
                + " or MUJOCO_GL=".join(OFFSCREEN_BACKENDS)
            ) from e
        self._gl, self._context = gl, context
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        # Free the context before the GL library shuts down (egl registers its own
        # atexit hook earlier; atexit runs hooks last-in first-out).
        atexit.register(self.close)
        return self

    def _camera(self, name: str | None) -> mujoco.MjvCamera:
        if name is None:
            return default_camera()
        names = [self.model.camera(i).name for i in range(self.model.ncam)]
        if name not in names:
            raise ValueError(
                f"camera {name!r} is not in the model; its cameras are {names} (default: "
                "a free camera on the workspace)"
            )
        camera = mujoco.MjvCamera()
        camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        camera.fixedcamid = self.model.camera(name).id
        return camera

    def frame(
        self,
        q: np.ndarray,
        target_pos: np.ndarray | None = None,
        target_quat: np.ndarray | None = None,
    ) -> np.ndarray:
        """(height, width, 3) uint8 RGB of the arm at q (6,) rad with the target marker
        at target_pos (3,) m / target_quat (w, x, y, z) (the model's default if None)."""
        if self._closed:
            raise RuntimeError("ArmRenderer.frame called after close()")
        self.open()
        set_pose(self.model, self.data, q, target_pos, target_quat)
        self._gl.make_current()
        mujoco.mjv_updateScene(
            self.model,
            self.data,
            self._option,
            None,
            self.camera,
            mujoco.mjtCatBit.mjCAT_ALL,
            self._scene,
        )
        mujoco.mjr_render(self._rect, self._scene, self._context)
        pixels = np.empty((self.height, self.width, 3), np.uint8)
        mujoco.mjr_readPixels(pixels, None, self._rect, self._context)
        return np.ascontiguousarray(pixels[::-1])  # OpenGL's rows run bottom-up

    def close(self) -> None:
        """Free the GL resources (idempotent); the renderer cannot be used afterwards."""
        self._closed = True
        atexit.unregister(self.close)
        if self._context is not None:
            self._gl.make_current()
            self._context.free()
            self._context = None
        if self._gl is not None:
            self._gl.free()
            self._gl = None

    def __enter__(self) -> ArmRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def check_display() -> None:
    """RenderError unless a desktop window can be opened (GLFW initialises)."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise RenderError(
            "no display for the MuJoCo viewer (DISPLAY and WAYLAND_DISPLAY are unset); "
            "run it on a desktop, or render offscreen instead (--video out.mp4 or "
            'render_mode="rgb_array")'
        )
    import glfw

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # glfw warns, then returns False
        ok = glfw.init()
    if not ok:
        where = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
        raise RenderError(
            f"cannot open a window on display {where!r} (GLFW failed to initialise); "
            'render offscreen instead (--video out.mp4 or render_mode="rgb_array")'
        )
    glfw.terminate()  # the viewer initialises GLFW again in its own thread


class Viewer:
    """The interactive MuJoCo viewer (`mujoco.viewer.launch_passive`) on a desktop,
    showing the poses given to `show`. RenderError if no window can be opened."""

    def __init__(self, model: mujoco.MjModel | None = None):
        check_display()
        import mujoco.viewer

        self.model = load_model() if model is None else model
        self.data = mujoco.MjData(self.model)
        set_pose(self.model, self.data, np.zeros(self.model.nq))
        _import_triton_first()
        try:
            self._handle = mujoco.viewer.launch_passive(
                self.model, self.data, show_left_ui=False, show_right_ui=False
            )
        except RuntimeError as e:  # macOS: launch_passive needs the mjpython launcher
            raise RenderError(
                f"cannot open the MuJoCo viewer: {e} (on macOS run `mjpython -m "
                "mara_mjx.play ...` instead of `python -m ...`)"
            ) from e
        with self._handle.lock():
            default_camera(self._handle.cam)
        self._handle.sync()

    @property
    def running(self) -> bool:
        """False once the user has closed the window."""
        return self._handle.is_running()

    def show(
        self,
        q: np.ndarray,
        target_pos: np.ndarray | None = None,
        target_quat: np.ndarray | None = None,
    ) -> None:
        """Show the arm at q (6,) rad and the target marker at its pose."""
        if not self.running:
            return
        with self._handle.lock():
            set_pose(self.model, self.data, q, target_pos, target_quat)
        self._handle.sync()

    def close(self) -> None:
        self._handle.close()
