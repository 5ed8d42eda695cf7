"""Writing a video of rendered frames: .mp4 (H.264 through imageio-ffmpeg's ffmpeg
binary, streamed) or .gif (Pillow), written beside the target and renamed onto it when
complete, never over a file that is not a video of that format unless asked
(`python -m mara_mjx.play --video`)."""

from __future__ import annotations

import os
import subprocess
import tempfile
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from mara_mjx.cli.common import UserError
from mara_mjx.runtime import files

VIDEO_MAGIC = {".mp4": (4, b"ftyp"), ".gif": (0, b"GIF8")}


def is_video(path: Path) -> bool:
    """Whether the regular file `path` starts like a video of its extension's format (an
    MP4 'ftyp' box, a GIF header): what --overwrite may replace."""
    offset, magic = VIDEO_MAGIC[path.suffix.lower()]
    try:
        if not path.is_file():
            return False
        with open(path, "rb") as f:
            head = f.read(offset + len(magic))
    except OSError:
        return False
    return head[offset:] == magic


def _temporary(path: Path) -> Path:
    """A new empty file beside `path` (its folder made if missing), named as the project's
    atomic writes name theirs."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return files.temporary(path)


class VideoWriter:
    """Frames (H, W, 3) uint8 into an .mp4 (H.264 through imageio-ffmpeg's ffmpeg binary,
    streamed) or a .gif (Pillow; held in memory as palette images, 1 byte a pixel).

    The video is written beside `path` under a temporary name and renamed onto it at
    `close()`; `abort()` removes it. `overwrite`: replace an existing `path` (otherwise
    a file that appeared there meanwhile is kept and the video is not written).

    ffmpeg is started with `process_group=0` instead of imageio-ffmpeg's
    `preexec_fn=os.setpgrp` (both keep Ctrl-C, sent to the terminal's process group,
    away from ffmpeg so that the frames so far are kept): a `preexec_fn` makes Python
    fork and run Python code in the child, which is what JAX warns about ("os.fork() was
    called ... JAX is multithreaded ... deadlock"); `process_group` is done by the C
    child code, with no Python at-fork hooks.
    """

    def __init__(
        self, path: Path, fps: float, width: int, height: int, overwrite: bool = False
    ) -> None:
        self.path, self.fps, self.frames, self.overwrite = Path(path), fps, 0, overwrite
        self.width, self.height = width, height
        self._gif: list[Any] | None = None
        self._proc: subprocess.Popen | None = None
        self._tmp: Path | None = None
        if self.path.suffix.lower() == ".gif":
            self._gif = []
            return
        import imageio_ffmpeg

        self._tmp = _temporary(self.path)
        cmd = [
            imageio_ffmpeg.get_ffmpeg_exe(),
            "-y", "-v", "warning",
            "-f", "rawvideo", "-vcodec", "rawvideo", "-pix_fmt", "rgb24",
            "-s", f"{width}x{height}", "-r", str(Fraction(fps).limit_denominator()),
            "-i", "-",
            "-an", "-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", "25",
            "-f", "mp4", str(self._tmp),
        ]  # fmt: skip
        self._log = tempfile.TemporaryFile()
        try:
            self._proc = subprocess.Popen(
                cmd,
                stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL,
                stderr=self._log,
                close_fds=True,
                process_group=0,
            )
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            self._log.close()
            raise

    def append(self, frame: np.ndarray) -> None:
        if frame.shape != (self.height, self.width, 3):
            raise ValueError(
                f"frame of shape {frame.shape}, expected {(self.height, self.width, 3)}"
            )
        if self._gif is not None:
            from PIL import Image

            self._gif.append(Image.fromarray(frame).quantize(colors=256))
        else:
            try:
                self._proc.stdin.write(np.ascontiguousarray(frame, np.uint8).tobytes())
            except BrokenPipeError as e:
                raise RuntimeError(f"ffmpeg stopped: {self._ffmpeg_log()}") from e
        self.frames += 1

    def _ffmpeg_log(self) -> str:
        self._log.seek(0)
        text = self._log.read().decode(errors="replace").strip()
        return text[-2000:] or f"exit status {self._proc.poll()}"

    def close(self) -> None:
        """Finish the file and move it onto `path` (no frames: nothing is written)."""
        if self.frames == 0:
            self.abort()
            return
        if self._proc is not None:
            proc, self._proc = self._proc, None
            try:
                proc.stdin.close()
                if proc.wait() != 0:
                    self._proc = proc
                    raise RuntimeError(f"ffmpeg failed: {self._ffmpeg_log()}")
                self._place(self._tmp)
            finally:
                self._proc = None
                self._log.close()
                self._tmp.unlink(missing_ok=True)
        if self._gif:
            first, *rest = self._gif
            self._gif = None
            # GIF delays are whole hundredths of a second.
            delay = max(10, int(round(100.0 / self.fps)) * 10)
            tmp = _temporary(self.path)
            try:
                with open(tmp, "wb") as f:
                    first.save(
                        f, format="GIF", save_all=True, append_images=rest, duration=delay, loop=0
                    )
                self._place(tmp)
            finally:
                tmp.unlink(missing_ok=True)

    def _place(self, tmp: Path) -> None:
        """Move the finished `tmp` onto `path`: replacing it with `overwrite`, else only
        if nothing is there (a hard link fails on an existing name)."""
        if self.overwrite:
            os.replace(tmp, self.path)
            return
        try:
            os.link(tmp, self.path)
        except FileExistsError:
            raise UserError(
                f"{self.path} appeared while playing (another program?); it is kept and "
                "the video is not written (--overwrite replaces it)"
            ) from None
        except OSError:  # no hard links on this file system
            if self.path.exists():
                raise UserError(
                    f"{self.path} appeared while playing; the video is not written"
                ) from None
            os.replace(tmp, self.path)

    def abort(self) -> None:
        """Stop without writing `path` (an error): ffmpeg is stopped, its file removed."""
        self._gif = None
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait()
            self._proc = None
            self._log.close()
        if self._tmp is not None:
            self._tmp.unlink(missing_ok=True)
