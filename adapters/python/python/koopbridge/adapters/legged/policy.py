"""An expert walking policy for a legged robot: an observation built from the floating-base state
in the robot's layout, run by onnxruntime on one thread, its actions turned into joint targets.
Robot-agnostic: the robot supplies its layout — ``ObservationLayout`` (legged-gym order, the
Go2's in ``legged.go2.model``) or ``PhaseObservationLayout`` (sorted terms with a gait phase, the G1's
in ``legged.g1.model``)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..._native import KoopbridgeError

__all__ = ["Layout", "ObservationLayout", "OnnxExpert", "PhaseObservationLayout", "PolicyError", "next_phase"]


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

    @property
    def phase_step(self) -> float | None:
        """No gait phase in this layout."""
        return None

    def observe(self, ang_vel: np.ndarray, gravity: np.ndarray, command: np.ndarray, q: np.ndarray, qd: np.ndarray,
                last_action: np.ndarray, phase: np.ndarray) -> np.ndarray:
        """The float64 observation (``phase`` unused), clipped to ±``obs_clip``."""
        obs = np.concatenate(
            [ang_vel * self.ang_vel_scale, gravity, command, q - np.asarray(self.default_pose), qd * self.joint_vel_scale, last_action]
        )
        return np.clip(obs, -self.obs_clip, self.obs_clip)


@dataclass(frozen=True)
class PhaseObservationLayout:
    """holosoma's locomotion observation (its ``loco_g1_29dof``): the terms concatenated in sorted
    name order — ``actions`` (the last action, n), ``base_ang_vel`` (body, × ``ang_vel_scale``,
    3), ``command_ang_vel`` (ωz, 1), ``command_lin_vel`` (vx, vy, 2), ``cos_phase`` (2),
    ``dof_pos`` (q − default, n), ``dof_vel`` (q̇ × ``joint_vel_scale``, n),
    ``projected_gravity`` (3), ``sin_phase`` (2): ``3n + 13`` values, not clipped. The phase
    of the two feet advances 2π·dt/``gait_period`` per step (``next_phase``). Action clipped to
    ±``action_clip``; joint targets = ``default_pose + action × action_scale``.
    """

    default_pose: tuple[float, ...]
    action_scale: tuple[float, ...]
    gait_period: float
    dt: float
    ang_vel_scale: float = 0.25
    joint_vel_scale: float = 0.05
    action_clip: float = 100.0

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.default_pose)

    @property
    def n_obs(self) -> int:
        """Observation length."""
        return 13 + 3 * self.n

    @property
    def phase_step(self) -> float:
        """How far the gait phase advances per policy step (rad)."""
        return 2 * math.pi * self.dt / self.gait_period

    def terms(self, ang_vel: np.ndarray, gravity: np.ndarray, command: np.ndarray, q: np.ndarray, qd: np.ndarray,
              last_action: np.ndarray, phase: np.ndarray) -> dict[str, np.ndarray]:
        """The observation's terms by holosoma's names, scaled."""
        return {
            "actions": last_action,
            "base_ang_vel": ang_vel * self.ang_vel_scale,
            "command_ang_vel": command[2:3],
            "command_lin_vel": command[0:2],
            "cos_phase": np.cos(phase),
            "dof_pos": q - np.asarray(self.default_pose),
            "dof_vel": qd * self.joint_vel_scale,
            "projected_gravity": gravity,
            "sin_phase": np.sin(phase),
        }

    def observe(self, ang_vel: np.ndarray, gravity: np.ndarray, command: np.ndarray, q: np.ndarray, qd: np.ndarray,
                last_action: np.ndarray, phase: np.ndarray) -> np.ndarray:
        """The float64 observation: ``terms`` in sorted name order."""
        t = self.terms(ang_vel, gravity, command, q, qd, last_action, phase)
        return np.concatenate([np.asarray(t[k], dtype=np.float64) for k in sorted(t)])


def next_phase(phase: np.ndarray, standing: bool, command: np.ndarray, step: float) -> tuple[np.ndarray, bool]:
    """holosoma's ``update_phase_time``: both feet advance ``step`` rad (wrapped to [−π, π));
    on a zero command (|v| and |ωz| < 0.01) both are held at π (standing); the first step after
    standing restarts them at (0, π). Returns (phase, standing)."""
    phase = np.fmod(phase + step + math.pi, 2 * math.pi) - math.pi
    if np.linalg.norm(command[0:2]) < 0.01 and abs(float(command[2])) < 0.01:
        return np.full(2, math.pi), True
    if standing:
        return np.array([0.0, math.pi]), False
    return phase, standing


class Layout(Protocol):
    """What ``OnnxExpert`` needs of an observation layout."""

    @property
    def n(self) -> int: ...
    @property
    def n_obs(self) -> int: ...
    @property
    def default_pose(self) -> tuple[float, ...]: ...
    @property
    def action_scale(self) -> tuple[float, ...]: ...
    @property
    def action_clip(self) -> float: ...
    @property
    def phase_step(self) -> float | None: ...
    def observe(self, ang_vel: np.ndarray, gravity: np.ndarray, command: np.ndarray, q: np.ndarray, qd: np.ndarray,
                last_action: np.ndarray, phase: np.ndarray) -> np.ndarray: ...


class OnnxExpert:
    """An ONNX velocity-tracking policy (one input ``(1, n_obs)`` float32, one output ``(1, n)``)
    on onnxruntime's CPU provider with one intra-op and one inter-op thread (deterministic, and
    cheap next to the physics). Holds the last action (part of the observation) and, for a
    layout with a gait period, the feet's phase (advanced before each action, ``next_phase``);
    ``reset()`` zeroes the action and restarts the phase at (0, π)."""

    def __init__(self, path: str, layout: Layout) -> None:
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
        self.reset()

    def reset(self) -> None:
        """Forget the last action; the gait phase restarts at (0, π)."""
        self.last_action = np.zeros(self.layout.n)
        self.phase = np.array([0.0, math.pi])
        self.standing = False

    def observation(self, ang_vel: np.ndarray, gravity: np.ndarray, command: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The float64 observation (before the float32 cast) at the current phase, joints in the
        policy's order."""
        return self.layout.observe(ang_vel, gravity, np.asarray(command, dtype=np.float64), q, qd, self.last_action, self.phase)

    def act(self, ang_vel: np.ndarray, gravity: np.ndarray, command: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Joint targets (rad, the policy's order) for the observed robot and ``command``
        (vx, vy, ωz); advances the gait phase first (if any) and remembers the action for the
        next observation."""
        step = self.layout.phase_step
        if step is not None:
            self.phase, self.standing = next_phase(self.phase, self.standing, np.asarray(command, dtype=np.float64), step)
        x = self.observation(ang_vel, gravity, command, q, qd).astype(np.float32)[None, :]
        (out,) = self.session.run(None, {self.input_name: x})
        action = np.clip(np.asarray(out[0], dtype=np.float64), -self.layout.action_clip, self.layout.action_clip)
        self.last_action = action
        targets: np.ndarray = self.default_pose + action * self.action_scale
        return targets
