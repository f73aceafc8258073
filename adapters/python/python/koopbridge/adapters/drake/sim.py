"""The Kinova Gen3 in a Drake ``MultibodyPlant`` (time step 1 ms) run by Drake's ``Simulator``,
commanded in joint velocities like the real arm, as a koopbridge simulator.

    python -m koopbridge.adapters.drake_sim --session S --id gen3

State ``[q (7), q̇ (7)]`` [rad, rad/s], input the commanded joint velocities (7) [rad/s] within
the kortex velocity limits. The low-level controller (the arm's own, in velocity mode) integrates
the commands into a position reference and tracks both with inverse dynamics (Drake's
``InverseDynamicsController``, gains ``kp``/``kd``), the torques clamped to the effort limits.
The reference restarts at the measured ``q`` at every ``step`` (it is integrated only within
one step), so ``[q, q̇]`` is the whole state: ``reset(x0=x)`` then ``step(u)`` gives what the
run that passed through ``x`` gave (``koopbridge.testing.check_adapter``). With the default
``dt`` = one plant step the position gain therefore never acts: the arm is velocity-servoed
(``kd``) on top of inverse dynamics, as a velocity-mode arm whose position is closed by the
caller.
``collect_plans`` executes planned trajectories (``drake.plan``) and cuts the log into windows
(named so because the SDK's ``collect(policy, seed, n_windows, T)`` means random-input windows).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._native import InvalidInput, KoopbridgeError
from ...collect import Windows
from ...serving import run_main
from ...simulator import SimInfo
from .model import CONTINUOUS, EFFORT_LIMITS, JOINT_NAMES, POSITION_LIMITS, VELOCITY_LIMITS, build_gen3
from .windows import DESCRIPTION as PLANNED_COLLECT

__all__ = ["DrakeGen3Sim", "X0_VELOCITY_FACTOR", "main", "parser", "simulator"]

#: ``reset(x0=)`` accepts joint velocities up to this multiple of the command limits.
X0_VELOCITY_FACTOR = 2.0


class DrakeGen3Sim:
    """The Gen3 simulation with the SDK's simulator methods (``info``, ``reset``, ``step``,
    ``close``) plus ``collect_plans``. ``dt``: the step of one ``step`` call, a whole number of plant time
    steps (``time_step``, 1 ms); ``kp`` [1/s²], ``kd`` [1/s]: the controller's gains;
    ``command_gain``: the actuators realise ``command_gain · u`` for a command ``u`` (a model
    mismatch that only feedback corrects; 1 = none)."""

    def __init__(
        self, dt: float = 0.001, time_step: float = 0.001, kp: float = 3600.0, kd: float = 120.0, command_gain: float = 1.0
    ) -> None:
        from importlib.metadata import version

        from pydrake.systems.analysis import Simulator
        from pydrake.systems.controllers import InverseDynamicsController
        from pydrake.systems.framework import DiagramBuilder
        from pydrake.systems.primitives import Saturation

        if not (time_step > 0 and dt > 0 and np.isfinite(dt)):
            raise InvalidInput(f"dt ({dt}) and time_step ({time_step}) must be positive")
        self.substeps = int(round(dt / time_step))
        if self.substeps < 1 or abs(self.substeps * time_step - dt) > 1e-12:
            raise InvalidInput(f"dt {dt} s must be a whole number of plant steps of {time_step} s")
        self.dt = float(dt)
        self.time_step = float(time_step)
        self.kp, self.kd = float(kp), float(kd)
        if not (np.isfinite(command_gain) and command_gain > 0):
            raise InvalidInput(f"command_gain must be finite and > 0, got {command_gain}")
        self.command_gain = float(command_gain)
        #: The gain of the episode: ``command_gain``, or a reset perturbation's.
        self.episode_gain = self.command_gain
        self.drake_version = version("drake")
        b = DiagramBuilder()
        self.gen3 = build_gen3(time_step=time_step, collision=False, builder=b, finalize_diagram=False)
        plant = self.gen3.plant
        # The controller's model of the arm: the same MJCF as a continuous plant of its own.
        self._control = build_gen3(time_step=0.0, collision=False)
        ctrl = b.AddSystem(InverseDynamicsController(self._control.plant, [kp] * 7, [0.0] * 7, [kd] * 7, False))
        sat = b.AddSystem(Saturation(-EFFORT_LIMITS, EFFORT_LIMITS))
        b.Connect(plant.get_state_output_port(self.gen3.model), ctrl.get_input_port_estimated_state())
        b.Connect(ctrl.get_output_port_control(), sat.get_input_port())
        b.Connect(sat.get_output_port(), plant.get_actuation_input_port(self.gen3.model))
        desired = b.ExportInput(ctrl.get_input_port_desired_state(), "desired_state")
        torque = b.ExportOutput(sat.get_output_port(), "torque")
        self.diagram = b.Build()
        self._desired = self.diagram.get_input_port(desired)
        self._torque = self.diagram.get_output_port(torque)
        self.simulator = Simulator(self.diagram)
        self.context = self.simulator.get_mutable_context()
        self.plant_context = plant.GetMyMutableContextFromRoot(self.context)
        self.q_lower = plant.GetPositionLowerLimits()
        self.q_upper = plant.GetPositionUpperLimits()
        self.ready = False
        self.k = 0
        self._planner: Any = None

    # ---- description ----
    def info(self) -> SimInfo:
        """What the simulator is (the SDK's ``info``): names, units, bounds, dt, Drake version."""
        names = [f"q{i + 1}" for i in range(7)] + [f"qd{i + 1}" for i in range(7)]
        return SimInfo(
            env="kinova-gen3",
            kind="drake",
            version=f"drake {self.drake_version}",
            dt=self.dt,
            state_names=names,
            input_names=[f"qd_cmd{i + 1}" for i in range(7)],
            u_min=(-VELOCITY_LIMITS).tolist(),
            u_max=VELOCITY_LIMITS.tolist(),
            angle_indices=[],
            extra=dict(drake=dict(
                version=self.drake_version,
                model="robosuite 1.5.2 models/assets/robots/kinova3/robot.xml (kortex_description inertials)",
                joints=JOINT_NAMES,
                units=dict(state=["rad"] * 7 + ["rad/s"] * 7, inputs=["rad/s"] * 7),
                position_limits=[None if np.isinf(v) else float(v) for v in POSITION_LIMITS],
                velocity_limits=VELOCITY_LIMITS.tolist(),
                effort_limits=EFFORT_LIMITS.tolist(),
                time_step=self.time_step,
                controller=dict(kind="inverse dynamics, velocity mode", kp=self.kp, kd=self.kd, command_gain=self.command_gain),
            ), planned_collect=PLANNED_COLLECT),
        )

    # ---- simulation ----
    def _check_state(self, x0: Any) -> np.ndarray:
        try:
            x = np.asarray(x0, dtype=float).ravel()
        except (TypeError, ValueError) as e:
            raise InvalidInput(f"x0 must be 14 numbers ({e})") from e
        if x.shape != (14,) or not np.all(np.isfinite(x)):
            raise InvalidInput(f"x0 must be 14 finite values [q (7), qd (7)], got {x.size} values")
        q, v = x[:7], x[7:]
        bad = np.flatnonzero((q < self.q_lower) | (q > self.q_upper))
        if bad.size:
            j = int(bad[0])
            raise InvalidInput(f"x0: joint {j + 1} at {q[j]:.4f} rad is outside its limits [{self.q_lower[j]:.4f}, {self.q_upper[j]:.4f}]")
        # The arm overshoots a command at the limit transiently (7 % seen under random commands),
        # so states the simulation reaches are accepted up to twice the command limits.
        bad = np.flatnonzero(np.abs(v) > X0_VELOCITY_FACTOR * VELOCITY_LIMITS)
        if bad.size:
            j = int(bad[0])
            raise InvalidInput(
                f"x0: joint {j + 1} velocity {v[j]:.4f} rad/s exceeds {X0_VELOCITY_FACTOR:g} x its command limit {VELOCITY_LIMITS[j]}"
            )
        return x

    def reset(self, seed: int | None = None, x0: Any = None, perturbation: dict[str, Any] | None = None) -> np.ndarray:
        """Starts at ``x0``, at rest at a configuration drawn uniformly within the limits with
        ``seed`` (continuous joints ±π), or (neither) at rest upright (q = 0). Returns x_0.
        ``perturbation`` (PROTOCOL.md "reset"): ``{"command_gain": g}`` makes the actuators realise
        ``g · u`` for this episode (g > 0; without it the simulator's own ``command_gain``); any
        other key is refused."""
        gain = self.command_gain
        if perturbation is not None:
            unknown = sorted(set(perturbation) - {"command_gain"})
            if unknown:
                raise InvalidInput(f"perturbation: the Kinova takes only command_gain, not {unknown}")
            g = perturbation.get("command_gain")
            if g is not None:
                try:
                    gain = float(g)
                except (TypeError, ValueError) as e:
                    raise InvalidInput(f"perturbation.command_gain must be a number, got {g!r}") from e
                if not (np.isfinite(gain) and gain > 0):
                    raise InvalidInput(f"perturbation.command_gain must be finite and > 0, got {g}")
        if x0 is not None:
            x = self._check_state(x0)
        elif seed is not None:
            hi = np.where(CONTINUOUS, np.pi, POSITION_LIMITS)
            x = np.concatenate([np.random.default_rng(seed).uniform(-hi, hi), np.zeros(7)])
        else:
            x = np.zeros(14)
        self.context.SetTime(0.0)
        self.gen3.plant.SetPositionsAndVelocities(self.plant_context, x)
        self._desired.FixValue(self.context, x.copy())
        self.ready = True
        self.simulator.Initialize()
        self.k = 0
        self.episode_gain = gain
        return self.state()

    def state(self) -> np.ndarray:
        """The current ``[q, q̇]``."""
        return self.gen3.plant.GetPositionsAndVelocities(self.plant_context).copy()

    def step(self, u: Any) -> np.ndarray:
        """Holds the velocity command ``u`` over one ``dt`` and returns the next state."""
        if not self.ready:
            raise InvalidInput("step before reset")
        try:
            u = np.asarray(u, dtype=float).ravel()
        except (TypeError, ValueError) as e:
            raise InvalidInput(f"u must be 7 numbers ({e})") from e
        if u.shape != (7,) or not np.all(np.isfinite(u)):
            raise InvalidInput(f"u must be 7 finite joint velocities [rad/s], got {u.tolist()}")
        bad = np.flatnonzero(np.abs(u) > VELOCITY_LIMITS * (1 + 1e-9))
        if bad.size:
            j = int(bad[0])
            raise InvalidInput(f"u: joint {j + 1} command {u[j]:.4f} rad/s exceeds its limit {VELOCITY_LIMITS[j]}")
        # The position reference starts at the measured q (no hidden state carried over).
        q_ref = self.state()[:7]
        u = self.episode_gain * u
        for i in range(self.substeps):
            self._desired.FixValue(self.context, np.concatenate([q_ref, u]))
            q_ref = q_ref + u * self.time_step
            # Times from the step count, not by adding dt: a sum that falls short of the plant's
            # update time would skip an update (and do two in the next step).
            self.simulator.AdvanceTo((self.k * self.substeps + i + 1) * self.time_step)
        self.k += 1
        x = self.state()
        if not np.all(np.isfinite(x)):
            self.ready = False
            raise KoopbridgeError(f"the Drake simulation diverged at step {self.k} (non-finite state); reset it")
        return x

    def torque(self) -> np.ndarray:
        """The joint torques [N·m] the controller applies at the current state."""
        return self._torque.Eval(self.context).copy()

    def close(self) -> None:
        """Nothing to release (kept for the SDK's protocol)."""

    def collect(self, policy: Any, seed: int, n_windows: int, T: int, start: int = 0) -> Windows:
        """The SDK's in-process collection: ``PlannedPolicy`` (or its JSON ``{"kind":
        "planned", ...}``) cuts windows from planned trajectories (``drake.windows``, an
        in-process ``Gen3Planner`` built on first use); any other policy draws its inputs per
        window from a seeded reset (``koopbridge.collect.collect_windows``)."""
        from ...collect import collect_windows, policy_from_json
        from .windows import PlannedPolicy, collect_planned

        if isinstance(policy, dict):
            policy = policy_from_json(policy)
        if isinstance(policy, PlannedPolicy):
            if self._planner is None:
                from .plan import Gen3Planner

                self._planner = Gen3Planner()
            return collect_planned(self, self._planner, policy, seed, n_windows, T, start)
        return collect_windows(self, policy, seed, n_windows, T, start=start)

    def collect_plans(self, planner: Any, goals: Sequence[Sequence[float]], steps: int = 15, x0: Any = None, on_plan: Any = None) -> dict[str, Any]:
        """Executes a plan to each goal in turn (each from where the arm is) with the planned
        velocities as commands, logging at ``dt``; returns ``x [n, steps+1, 14]`` and
        ``u [n, steps, 7]`` (non-overlapping windows of ``steps`` transitions, none spanning two
        plans) plus ``plans``: per goal the duration, steps, windows, solver reports or the
        ``infeasible`` error (that goal is then skipped). ``on_plan(i, record)`` is called after
        each goal."""
        from .plan import Infeasible

        if steps < 1:
            raise InvalidInput(f"steps must be at least 1, got {steps}")
        x = self.reset(x0=x0) if x0 is not None else self.reset()
        xs: list[np.ndarray] = []
        us: list[np.ndarray] = []
        records = []
        for i, goal in enumerate(goals):
            rec: dict[str, Any] = dict(goal=np.asarray(goal, float).tolist(), start=x[:7].tolist())
            start = np.clip(x[:7], self.q_lower, self.q_upper)
            try:
                plan = planner.plan(start, goal)
            except Infeasible as e:
                rec.update(error=dict(code=e.code, message=str(e), pass_name=e.pass_name))
                records.append(rec)
                if on_plan:
                    on_plan(i, rec)
                continue
            _, _, qd = plan.sample(self.dt)
            cmds = np.clip(qd[:-1], -VELOCITY_LIMITS, VELOCITY_LIMITS)
            log_x = [x]
            for u in cmds:
                x = self.step(u)
                log_x.append(x)
            lx, lu = np.array(log_x), np.asarray(cmds)
            n = len(cmds) // steps
            for w in range(n):
                xs.append(lx[w * steps : (w + 1) * steps + 1])
                us.append(lu[w * steps : (w + 1) * steps])
            final_err = float(np.max(np.abs(x[:7] - plan.goal)))
            rec.update(duration=plan.duration, steps=len(cmds), windows=n, final_error=final_err, passes=[p.__dict__ for p in plan.passes])
            records.append(rec)
            if on_plan:
                on_plan(i, rec)
        return dict(
            x=np.array(xs).reshape(-1, steps + 1, 14),
            u=np.array(us).reshape(-1, steps, 7),
            plans=records,
        )


def parser() -> argparse.ArgumentParser:
    """The Drake simulator adapter's own options (``run_main`` adds ``--describe`` and the
    serving ones)."""
    p = argparse.ArgumentParser(
        prog="python -m koopbridge.adapters.drake_sim",
        description="Serve the Kinova Gen3 in a Drake simulation (velocity commands, state [q, qd]) as a koopbridge simulator over Zenoh.",
    )
    p.add_argument("--dt", type=float, default=0.001, help="step of one step() in seconds, a multiple of 1 ms (default: %(default)s)")
    p.add_argument("--kp", type=float, default=3600.0, help="controller position gain [1/s^2] (default: %(default)s)")
    p.add_argument("--kd", type=float, default=120.0, help="controller velocity gain [1/s] (default: %(default)s)")
    p.add_argument("--command-gain", type=float, default=1.0,
                   help="the actuators realise this multiple of each command: a model mismatch for robustness tests (default: %(default)s)")
    return p


def simulator(args: argparse.Namespace) -> DrakeGen3Sim:
    """The ``DrakeGen3Sim`` the parsed command line describes."""
    return DrakeGen3Sim(dt=args.dt, kp=args.kp, kd=args.kd, command_gain=args.command_gain)


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the Drake simulator adapter (``koopbridge.serving.run_main``); returns the exit code."""
    return run_main(simulator, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
