"""Two-pass kinematic trajectory optimisation of the Kinova Gen3 with Drake (SPEC, "Kinova data"):
B-spline paths between joint configurations, then the same with minimum-distance constraints.

Pass ``kinematic``: ``KinematicTrajectoryOptimization`` with 10 control points, cost duration +
path length, duration in [0.5, 5] s, position and velocity limits, start and goal positions and
zero velocity at both ends. Pass ``collision``: the same problem started from the first pass's
solution, plus a minimum distance (self-collision and the table) at evenly spaced path points.
Each pass is solved with SNOPT, IPOPT when SNOPT fails or is missing. No networking here.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..._native import InvalidInput, KoopbridgeError
from .model import CONTINUOUS, POSITION_LIMITS, VELOCITY_LIMITS, build_gen3

__all__ = ["DimensionError", "Gen3Planner", "Infeasible", "PassReport", "Plan", "random_goals"]

PASSES = ("kinematic", "collision")


class DimensionError(InvalidInput):
    """A configuration has the wrong number of values (the protocol's ``dimension`` error)."""

    code = "dimension"


class Infeasible(KoopbridgeError):
    """No trajectory: ``pass_name`` is the pass that failed, ``statuses`` each solver's status."""

    code = "infeasible"

    def __init__(self, pass_name: str, statuses: Sequence[str]) -> None:
        self.pass_name = pass_name
        self.statuses = list(statuses)
        super().__init__(f"no trajectory: pass '{pass_name}' failed ({'; '.join(self.statuses)})")


@dataclass
class PassReport:
    """One solved pass: which solver answered, its status, wall and CPU time of the pass (every
    solver tried) [s] and the cost."""

    name: str
    solver: str
    status: str
    solve_time_s: float
    cost: float
    attempts: list[str] = field(default_factory=list)
    cpu_time_s: float = 0.0


@dataclass
class Plan:
    """A planned trajectory: the ``trajectory`` (Drake ``BsplineTrajectory`` in time, from 0 to
    ``duration`` [s]) and the report of each pass."""

    start: np.ndarray
    goal: np.ndarray
    duration: float
    trajectory: Any
    passes: list[PassReport]

    def sample(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Times ``t_k = k·dt`` for k = 0..ceil(duration/dt) (the last clamped to the duration),
        positions ``[n, 7]`` and velocities ``[n, 7]`` at those times."""
        if not (np.isfinite(dt) and dt > 0):
            raise InvalidInput(f"dt must be a positive number of seconds, got {dt}")
        n = int(np.ceil(self.duration / dt - 1e-9)) + 1
        if n > 1_000_000:
            raise InvalidInput(f"dt {dt} s gives {n} samples for a {self.duration:.3f} s plan (at most 1000000)")
        t = np.minimum(np.arange(n) * dt, self.duration)
        qd_traj = self.trajectory.MakeDerivative()
        q = np.array([self.trajectory.value(ti).ravel() for ti in t])
        qd = np.array([qd_traj.value(ti).ravel() for ti in t])
        return t, q, qd


def random_goals(seed: int, n: int, planner: Gen3Planner | None = None, margin: float = 0.0) -> np.ndarray:
    """``n`` joint-space goals ``[n, 7]`` drawn uniformly within the joint limits (continuous
    joints: ±π), reproducible by ``seed``. With a ``planner``, draws that are closer than
    ``margin`` [m] to a collision (self or table) are redrawn (rejection sampling)."""
    rng = np.random.default_rng(seed)
    hi = np.where(CONTINUOUS, np.pi, POSITION_LIMITS)
    out = np.empty((n, 7))
    for i in range(n):
        for _ in range(10_000):
            q = rng.uniform(-hi, hi)
            if planner is None or planner.min_distance(q) >= margin:
                break
        else:
            raise KoopbridgeError(f"no collision-free goal in 10000 draws (seed {seed})")
        out[i] = q
    return out


class Gen3Planner:
    """Plans Gen3 trajectories (see the module doc). ``min_distance`` [m] is the clearance of the
    collision pass, enforced at ``collision_samples`` path points; ``solvers`` is the order in
    which they are tried (``snopt``, ``ipopt``); ``table_z``: height of the table top [m];
    ``ipopt_max_iterations``: IPOPT's iteration limit per pass (it is the fallback after SNOPT
    failed; at its default 3000 it spent 39 s on one infeasible goal). An iteration count, not a
    time, so that the same request plans the same way on any machine and under any load."""

    def __init__(
        self,
        num_control_points: int = 10,
        min_duration: float = 0.5,
        max_duration: float = 5.0,
        min_distance: float = 0.01,
        collision_samples: int = 25,
        solvers: Sequence[str] = ("snopt", "ipopt"),
        table_z: float | None = 0.0,
        ipopt_max_iterations: int = 300,
    ) -> None:
        from pydrake.solvers import IpoptSolver, SnoptSolver, SolverOptions

        self.num_control_points = int(num_control_points)
        self.min_duration = float(min_duration)
        self.max_duration = float(max_duration)
        self.min_distance_bound = float(min_distance)
        self.collision_samples = int(collision_samples)
        known = {"snopt": SnoptSolver, "ipopt": IpoptSolver}
        self.solvers = []
        for s in solvers:
            if s not in known:
                raise InvalidInput(f"unknown solver '{s}' (known: snopt, ipopt)")
            solver = known[s]()
            if solver.available() and solver.enabled():
                self.solvers.append((s, solver))
        if not self.solvers:
            raise KoopbridgeError(f"none of the solvers {list(solvers)} is available in this Drake build")
        if int(ipopt_max_iterations) < 1:
            raise InvalidInput(f"ipopt_max_iterations must be at least 1, got {ipopt_max_iterations}")
        self.options = SolverOptions()
        self.options.SetOption(IpoptSolver.id(), "max_iter", int(ipopt_max_iterations))
        self.gen3 = build_gen3(time_step=0.0, collision=True, table_z=table_z)
        self.plant = self.gen3.plant
        self.diagram_context = self.gen3.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyContextFromRoot(self.diagram_context)
        self.q_lower = self.plant.GetPositionLowerLimits()
        self.q_upper = self.plant.GetPositionUpperLimits()
        self.v_upper = VELOCITY_LIMITS.copy()
        self.filtered_pairs = self._filter_pairs_in_contact_at_home()

    # ---- geometry ----
    def _distances(self, q: np.ndarray) -> list[Any]:
        self.plant.SetPositions(self.plant_context, q)
        qo = self.plant.get_geometry_query_input_port().Eval(self.plant_context)
        return qo.ComputeSignedDistancePairwiseClosestPoints(max_distance=1.0)

    def _filter_pairs_in_contact_at_home(self) -> list[tuple[str, str]]:
        """Excludes the geometry pairs that touch (closer than 1 mm) at q = 0, the upright arm:
        neighbouring links' hulls and the shoulder resting on the table overlap there whatever
        the motion (the role of an SRDF's disabled collisions)."""
        from pydrake.geometry import CollisionFilterDeclaration, GeometrySet

        inspector = self.gen3.scene_graph.model_inspector()
        manager = self.gen3.scene_graph.collision_filter_manager(self.gen3.scene_graph.GetMyMutableContextFromRoot(self.diagram_context))
        pairs = []
        for d in self._distances(np.zeros(7)):
            if d.distance < 1e-3:
                manager.Apply(CollisionFilterDeclaration().ExcludeBetween(GeometrySet(d.id_A), GeometrySet(d.id_B)))
                pairs.append((inspector.GetName(d.id_A), inspector.GetName(d.id_B)))
        return pairs

    def min_distance(self, q: Sequence[float]) -> float:
        """The smallest signed distance [m] between the geometry pairs checked at ``q`` (negative
        when two overlap; 1.0 when every pair is farther than 1 m)."""
        ds = self._distances(np.asarray(q, float))
        return min((d.distance for d in ds), default=1.0)

    # ---- checks ----
    def check_configuration(self, q: Any, what: str) -> np.ndarray:
        """``q`` as 7 finite values within the position limits, else ``DimensionError`` or
        ``InvalidInput`` naming ``what`` and the offending joint."""
        try:
            a = np.asarray(q, dtype=float).ravel()
        except (TypeError, ValueError) as e:
            raise InvalidInput(f"{what} must be 7 numbers ({e})") from e
        if a.shape != (7,):
            raise DimensionError(f"{what} has {a.size} values, the Gen3 has 7 joints")
        if not np.all(np.isfinite(a)):
            raise InvalidInput(f"{what} has non-finite values: {a.tolist()}")
        bad = np.flatnonzero((a < self.q_lower - 1e-9) | (a > self.q_upper + 1e-9))
        if bad.size:
            j = int(bad[0])
            raise InvalidInput(f"{what}: joint {j + 1} at {a[j]:.4f} rad is outside its limits [{self.q_lower[j]:.4f}, {self.q_upper[j]:.4f}]")
        return a

    # ---- optimisation ----
    def _problem(self, start: np.ndarray, goal: np.ndarray) -> Any:
        from pydrake.planning import KinematicTrajectoryOptimization

        trajopt = KinematicTrajectoryOptimization(7, self.num_control_points, spline_order=4, duration=1.0)
        prog = trajopt.get_mutable_prog()
        trajopt.AddDurationCost(1.0)
        trajopt.AddPathLengthCost(1.0)
        trajopt.AddPositionBounds(self.q_lower, self.q_upper)
        trajopt.AddVelocityBounds(-self.v_upper, self.v_upper)
        trajopt.AddDurationConstraint(self.min_duration, self.max_duration)
        trajopt.AddPathPositionConstraint(start, start, 0.0)
        trajopt.AddPathPositionConstraint(goal, goal, 1.0)
        zero = np.zeros(7)
        trajopt.AddPathVelocityConstraint(zero, zero, 0.0)
        trajopt.AddPathVelocityConstraint(zero, zero, 1.0)
        # Straight line, slow enough for the velocity limits: a feasible-looking first guess.
        guess_T = float(np.clip(2.0 * np.max(np.abs(goal - start) / self.v_upper), self.min_duration, self.max_duration))
        prog.SetInitialGuess(trajopt.control_points(), np.linspace(start, goal, self.num_control_points).T)
        prog.SetInitialGuess(trajopt.duration(), guess_T)
        return trajopt, prog

    def _add_collision(self, trajopt: Any) -> None:
        from pydrake.multibody.inverse_kinematics import MinimumDistanceLowerBoundConstraint

        c = MinimumDistanceLowerBoundConstraint(self.plant, self.min_distance_bound, self.plant_context, None, 0.05)
        for s in np.linspace(0.0, 1.0, self.collision_samples):
            trajopt.AddPathPositionConstraint(c, s)

    def _solve(self, name: str, prog: Any, guess: np.ndarray | None) -> tuple[Any, PassReport]:
        attempts = []
        t0, c0 = time.perf_counter(), time.process_time()
        for sname, solver in self.solvers:
            result = solver.Solve(prog, guess, self.options)
            status = _status(sname, result)
            attempts.append(f"{sname}: {status}")
            if result.is_success():
                wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                return result, PassReport(name, sname, status, wall, float(result.get_optimal_cost()), attempts, cpu)
        raise Infeasible(name, attempts)

    def plan(self, start: Any, goal: Any, collision: bool = True) -> Plan:
        """A trajectory from ``start`` to ``goal`` (two passes; the first only when not
        ``collision``). Raises ``Infeasible`` naming the pass that failed, ``InvalidInput`` or
        ``DimensionError`` for bad configurations."""
        start = self.check_configuration(start, "start")
        goal = self.check_configuration(goal, "goal")
        trajopt, prog = self._problem(start, goal)
        result, first = self._solve(PASSES[0], prog, None)
        passes = [first]
        if collision:
            for what, q in (("start", start), ("goal", goal)):
                d = self.min_distance(q)
                if d < self.min_distance_bound:
                    raise Infeasible(PASSES[1], [f"the {what} configuration is {d * 1000:.1f} mm from a collision (needs {self.min_distance_bound * 1000:.1f} mm)"])
            self._add_collision(trajopt)
            result, second = self._solve(PASSES[1], prog, result.GetSolution(prog.decision_variables()))
            passes.append(second)
        traj = trajopt.ReconstructTrajectory(result)
        duration = float(traj.end_time() - traj.start_time())
        return Plan(start=start, goal=goal, duration=duration, trajectory=traj, passes=passes)


def _status(name: str, result: Any) -> str:
    """The solver's status in words: Drake's solution result plus the solver's own code."""
    base = str(result.get_solution_result()).split(".")[-1]
    try:
        details = result.get_solver_details()
        if name == "snopt":
            return f"{base}, SNOPT info {details.info}"
        if name == "ipopt":
            return f"{base}, IPOPT status {details.status} ({details.ConvertStatusToString()})"
    except Exception:  # details differ between Drake versions; the solution result suffices
        pass
    return base
