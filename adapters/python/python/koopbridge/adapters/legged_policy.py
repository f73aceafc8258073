"""An expert walking policy for a legged robot: a legged-gym-layout observation built from the
floating-base state, run by onnxruntime on one thread, its actions turned into joint targets.
Robot-agnostic: the robot supplies its ``ObservationLayout`` (the Go2's is in ``go2_model``)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .._native import KoopbridgeError

__all__ = ["ObservationLayout", "OnnxExpert", "PolicyError"]


class PolicyError(KoopbridgeError):
    """The expert policy cannot be loaded or run; the message names the file."""


@dataclass(frozen=True)
class ObservationLayout:
    """The legged-gym velocity-tracking observation and action convention.

    Observation (``3 + 3 + 3 + 3n`` values): ``[base angular velocity (body) × ang_vel_scale,
    projected gravity, command (vx, vy, ωz), q − default_pose, q̇ × joint_vel_scale, last
    action]``, clipped to ±``obs_clip``; action clipped to ±``action_clip``; joint targets =
    ``default_pose + action × action_scale``. Joint order: the policy's.
    """

    default_pose: tuple[float, ...]
    action_scale: tuple[float, ...]
    ang_vel_scale: float = 0.25
    joint_vel_scale: float = 0.05
    obs_clip: float = 100.0
    action_clip: float = 100.0

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.default_pose)

    @property
    def n_obs(self) -> int:
        """Observation length."""
        return 9 + 3 * self.n


class OnnxExpert:
    """An ONNX velocity-tracking policy (one input ``(1, n_obs)`` float32, one output ``(1, n)``)
    on onnxruntime's CPU provider with one intra-op and one inter-op thread (deterministic, and
    cheap next to the physics). Holds the last action (part of the observation);
    ``reset()`` zeroes it."""

    def __init__(self, path: str, layout: ObservationLayout) -> None:
        if not os.path.isfile(path):
            raise PolicyError(f"expert policy file {path} does not exist")
        try:
            import onnxruntime as ort
        except ImportError as e:  # pragma: no cover - pinned in requirements.txt
            raise PolicyError(f"running the expert policy {path} needs onnxruntime (pip install -r requirements.txt): {e}") from e
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        options.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])
        except Exception as e:
            raise PolicyError(f"expert policy file {path} is not a loadable ONNX model: {e}") from e
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if len(inputs) != 1 or list(inputs[0].shape)[-1] != layout.n_obs or list(outputs[0].shape)[-1] != layout.n:
            raise PolicyError(
                f"expert policy {path}: expects {[list(i.shape) for i in inputs]} -> {[list(o.shape) for o in outputs]}, "
                f"this robot needs (1, {layout.n_obs}) -> (1, {layout.n})"
            )
        self.path = path
        self.layout = layout
        self.input_name = inputs[0].name
        self.default_pose = np.array(layout.default_pose, dtype=np.float64)
        self.action_scale = np.array(layout.action_scale, dtype=np.float64)
        self.last_action = np.zeros(layout.n)

    def reset(self) -> None:
        """Forget the last action."""
        self.last_action = np.zeros(self.layout.n)

    def observation(self, ang_vel: np.ndarray, gravity: np.ndarray, command: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The float64 observation (before the float32 cast), joints in the policy's order."""
        lay = self.layout
        obs = np.concatenate(
            [ang_vel * lay.ang_vel_scale, gravity, command, q - self.default_pose, qd * lay.joint_vel_scale, self.last_action]
        )
        return np.clip(obs, -lay.obs_clip, lay.obs_clip)

    def act(self, ang_vel: np.ndarray, gravity: np.ndarray, command: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Joint targets (rad, the policy's order) for the observed robot and ``command``
        (vx, vy, ωz); remembers the action for the next observation."""
        x = self.observation(ang_vel, gravity, command, q, qd).astype(np.float32)[None, :]
        (out,) = self.session.run(None, {self.input_name: x})
        action = np.clip(np.asarray(out[0], dtype=np.float64), -self.layout.action_clip, self.layout.action_clip)
        self.last_action = action
        targets: np.ndarray = self.default_pose + action * self.action_scale
        return targets
