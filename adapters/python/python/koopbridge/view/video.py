"""MP4s of chosen references: each closed loop of a MuJoCo simulator rendered offscreen (EGL or
OSMesa, no GPU needed), the robot beside its reference, the step and the tracking error in the
frame; one file per simulator, row and reference."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .robots import RobotPoser

__all__ = ["VideoWriter", "parse_episodes"]


def parse_episodes(text: str) -> set[int]:
    """``--video 0,3,17``: reference indices (a ``[control]`` loop counts as reference 0);
    ``ValueError`` naming a value that is not a non-negative integer."""
    out = set()
    for part in text.split(","):
        part = part.strip()
        if not part.isdigit():
            raise ValueError(f"--video: {part!r} is not a reference index (a non-negative integer); e.g. --video 0,3")
        out.add(int(part))
    return out


@dataclass
class _Clip:
    path: Path
    frames: list[np.ndarray] = field(default_factory=list)


class VideoWriter:
    """Renders the loops of references ``episodes`` into ``folder`` (``{sim}-{row}-ref{i}.mp4``)
    at ``fps`` frames per second, ``width`` × ``height`` per robot (the frame is twice as wide)."""

    def __init__(self, folder: Path, episodes: set[int], fps: float = 25.0, width: int = 320, height: int = 240) -> None:
        self.folder, self.episodes, self.fps = folder, episodes, fps
        self.width, self.height = width, height
        self._clips: dict[tuple[str, str, int], _Clip] = {}
        self._renderers: dict[int, tuple[Any, Any]] = {}
        self.written: list[Path] = []

    def wants(self, episode: int | None) -> bool:
        return (0 if episode is None else episode) in self.episodes

    def add(
        self, robot: RobotPoser, sim: str, row: str, episode: int | None, k: int, dt: float, x: np.ndarray, ref: np.ndarray | None, last: bool = False
    ) -> None:
        """One state of a loop: a frame of the robot at ``x`` beside the reference ``ref``; the
        loop's ``last`` state writes its file (so that no finished loop is held in memory)."""
        stride = max(1, round(1.0 / (self.fps * dt))) if dt > 0 else 1
        if k % stride and not last:
            return  # frames at about `fps` of simulated time
        key = (sim, row, 0 if episode is None else episode)
        clip = self._clips.get(key)
        if clip is None or (k == 0 and clip.frames):
            if clip is not None:
                self._write(clip)
            name = "".join(c if c.isalnum() or c in "-_." else "_" for c in f"{sim}-{row}-ref{key[2]:03d}")
            clip = self._clips[key] = _Clip(self.folder / f"{name}.mp4")
        left = self._render(robot, x)
        if left is None:
            return
        right = self._render(robot, ref) if ref is not None else None
        frame = np.concatenate([left, right if right is not None else np.zeros_like(left)], axis=1)
        error = float(np.mean(np.abs(x - ref))) if ref is not None and len(ref) == len(x) else float("nan")
        clip.frames.append(_caption(frame, f"{sim} · {row} · reference {key[2]}", f"step {k}  t = {k * dt:.2f} s  mean |x - r| = {error:.3f}"))
        if last:
            self._write(clip)

    def _render(self, robot: RobotPoser, x: np.ndarray) -> np.ndarray | None:
        import mujoco

        qpos = robot.qpos_of(x)
        if qpos is None or not np.all(np.isfinite(qpos)):
            return None
        r = self._renderers.get(id(robot))
        if r is None:
            model = robot.model
            model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
            model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
            model.vis.quality.offsamples = 0  # no multisampling: half the time on a software renderer
            r = (mujoco.Renderer(model, self.height, self.width), mujoco.MjData(model))
            self._renderers[id(robot)] = r
        renderer, d = r
        d.qpos[:] = qpos
        mujoco.mj_forward(robot.model, d)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        body = 1 if robot.model.nbody > 1 else 0
        cam.lookat[:] = d.subtree_com[body]
        cam.distance = float(np.clip(1.6 * robot.model.stat.extent, 0.8, 4.0))
        cam.azimuth, cam.elevation = 135.0, -20.0
        visual = mujoco.MjvOption()
        visual.geomgroup[:] = [1, 1, 1, 0, 0, 0]  # the visual groups only (as RobotPoser draws)
        renderer.update_scene(d, camera=cam, scene_option=visual)
        return renderer.render().copy()

    def _write(self, clip: _Clip) -> None:
        import imageio.v3 as iio

        if not clip.frames:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        part = clip.path.with_name(clip.path.name + ".part.mp4")
        iio.imwrite(part, np.stack(clip.frames), fps=self.fps, codec="libx264", macro_block_size=16)
        part.replace(clip.path)
        if clip.path not in self.written:
            self.written.append(clip.path)
        clip.frames.clear()

    def close(self) -> list[Path]:
        """Writes every clip still open; the files written."""
        for clip in self._clips.values():
            self._write(clip)
        for renderer, _ in self._renderers.values():
            renderer.close()
        self._renderers.clear()
        return self.written


def _caption(frame: np.ndarray, title: str, line: str) -> np.ndarray:
    """``frame`` with two lines of text at its top left (and "robot" / "reference" under each half)."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(frame)
    draw = ImageDraw.Draw(img)
    w = frame.shape[1] // 2
    for x, y, text in ((8, 6, title), (8, 22, line), (8, frame.shape[0] - 20, "robot"), (w + 8, frame.shape[0] - 20, "reference")):
        draw.text((x + 1, y + 1), text, fill=(0, 0, 0))
        draw.text((x, y), text, fill=(255, 255, 255))
    return np.asarray(img)
