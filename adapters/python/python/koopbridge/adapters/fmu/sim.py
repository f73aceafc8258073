"""An FMI 2.0 / 3.0 co-simulation FMU as a discrete-time simulator ``x_{k+1} = f(x_k, u_k)``
through fmpy: inputs and outputs chosen by variable name, one ``doStep`` of ``dt`` per step with
the inputs held, reset by re-initialising the FMU. A ``koopbridge.Simulator``; no networking here
(see ``fmu.__main__``)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from ctypes import byref
from typing import Any

import numpy as np

from ..._native import InvalidInput, Unsupported
from ...simulator import SimInfo
from .variables import Accessor, Component, FmuError, Variables

__all__ = ["FmuError", "FmuSimulator"]


def _start_value(type_name: str | None, start: Any) -> Any:
    """A variable's start value as JSON: a number for numeric types, a bool for Boolean, the
    model description's text otherwise (None when there is none)."""
    if start is None:
        return None
    text = str(start).strip()
    if type_name == "Boolean" and len(text.split()) == 1:
        return text in ("true", "1")
    if type_name in ("String", "Binary", "Clock"):
        return text
    if len(text.split()) > 1:  # an FMI 3 array's start values
        return [_start_value(type_name, t) for t in text.split()]
    try:
        value = float(text)
    except ValueError:
        return text
    if type_name and ("Int" in type_name or type_name == "Enumeration") and value.is_integer():
        return int(value)
    return value


class FmuSimulator:
    """One FMU instance driven step by step.

    ``path``: the ``.fmu`` file; ``inputs``/``outputs``: variable names that form u and x;
    ``dt``: communication step (default: the FMU's default experiment step size);
    ``initial``: variable names (one per output) set to ``x0`` before initialisation (e.g. the
    FMU's initial-state parameters; default: the outputs themselves when they can be set, else
    none); ``x0_low``/``x0_high``: range of the uniform initial-state draw of a seeded reset;
    ``u_min``/``u_max``: input bounds reported in ``info`` (default: the variables' min/max);
    ``parameters``: start values to set on every reset (checked here; FMI 3 structural
    parameters first, so they may size arrays); ``env``, ``angle_indices``: reported.

    Names may be variables of any numeric FMI type, an FMI 3 array (all its elements ``y[0]``,
    ``y[1]``, ...) or one element (``y[1]``, ``M[0,1]``); see ``fmu.variables`` for the
    conversions. What cannot be served raises ``FmuError`` here, at construction; a value that
    cannot be represented raises ``InvalidInput`` in ``reset``/``step`` before the FMU is touched.
    """

    def __init__(
        self,
        path: str,
        inputs: Sequence[str],
        outputs: Sequence[str],
        dt: float | None = None,
        initial: Sequence[str] | None = None,
        x0_low: Sequence[float] | None = None,
        x0_high: Sequence[float] | None = None,
        u_min: Sequence[float] | None = None,
        u_max: Sequence[float] | None = None,
        parameters: dict[str, float] | None = None,
        env: str | None = None,
        angle_indices: Sequence[int] = (),
    ) -> None:
        import fmpy
        from fmpy import read_model_description

        self.path = os.path.abspath(path)
        self.name = os.path.basename(path)
        if not os.path.isfile(self.path):
            raise FmuError(f"FMU '{path}': file not found")
        try:
            md = read_model_description(self.path)
        except Exception as e:  # fmpy raises several types for broken archives and XML
            raise FmuError(f"FMU '{self.name}': cannot read its modelDescription.xml ({e})") from e
        if md.coSimulation is None:
            has = "model exchange only" if md.modelExchange is not None else "neither co-simulation nor model exchange"
            if getattr(md, "scheduledExecution", None) is not None:
                has = "scheduled execution" + (" and model exchange" if md.modelExchange is not None else "") + " only"
            raise FmuError(f"FMU '{self.name}': it has no co-simulation interface (FMI {md.fmiVersion}; {has})")
        if md.fmiVersion not in ("2.0",) and not md.fmiVersion.startswith("3."):
            raise FmuError(f"FMU '{self.name}': FMI version {md.fmiVersion} is not supported (2.0 and 3.x are)")
        self.md = md
        self.fmi3 = md.fmiVersion.startswith("3.")
        if not outputs:
            raise FmuError(f"FMU '{self.name}': no output variables chosen (the state x)")
        self.parameters = dict(parameters or {})
        vs = self.variables_ = Variables(md, self.name, self.parameters, self.path)
        self.vars = vs.by_name
        param_comps = vs.resolve(list(self.parameters), "parameter")
        for c in param_comps:
            if c.var.dimensions:
                raise FmuError(f"FMU '{self.name}': parameter '{c.var.name}' is an array; --param sets scalars only")
        self.in_comps = vs.resolve(inputs, "input")
        self.out_comps = vs.resolve(outputs, "output")
        self.inputs = [c.name for c in self.in_comps]
        self.outputs = [c.name for c in self.out_comps]
        default_dt = md.defaultExperiment.stepSize if md.defaultExperiment is not None else None
        self.dt = float(dt if dt is not None else (default_dt or 0.0))
        if not (self.dt > 0 and np.isfinite(self.dt)):
            raise FmuError(f"FMU '{self.name}': no communication step given and none in its default experiment")
        if initial is None:
            settable = all(c.var.causality in ("input", "parameter") or getattr(c.var, "initial", None) in ("exact", "approx") for c in self.out_comps)
            initial = list(self.outputs) if settable else []
        self.init_comps = vs.resolve(initial, "initial")
        self.initial = [c.name for c in self.init_comps]
        if self.initial and len(self.initial) != len(self.outputs):
            raise FmuError(f"FMU '{self.name}': {len(self.initial)} initial-state variables for {len(self.outputs)} outputs")
        nx = len(self.outputs)
        self.x0_low = None if x0_low is None else np.asarray(x0_low, float)
        self.x0_high = None if x0_high is None else np.asarray(x0_high, float)
        for what, r in (("x0_low", self.x0_low), ("x0_high", self.x0_high)):
            if r is not None and r.shape != (nx,):
                raise FmuError(f"FMU '{self.name}': {what} has {r.size} values, the state has {nx}")
        self.u_min = self._bounds(u_min, "min", -np.inf)
        self.u_max = self._bounds(u_max, "max", np.inf)
        self.env = env or md.modelName
        self.angle_indices = list(angle_indices)
        # The parameters are converted and checked here, at start-up; structural ones are set first.
        structural = [c for c in param_comps if c.var.causality == "structuralParameter"]
        others = [c for c in param_comps if c.var.causality != "structuralParameter"]
        self._params = []
        for comps in (structural, others):
            if comps:
                acc = Accessor(comps, vs, "parameter")
                try:
                    self._params.append((acc, acc.convert([self.parameters[c.var.name] for c in comps])))
                except InvalidInput as e:
                    raise FmuError(str(e)) from e
        self._in = Accessor(self.in_comps, vs, "input")
        self._out = Accessor(self.out_comps, vs, "output")
        self._init = Accessor(self.init_comps, vs, "initial")
        self.log: list[str] = []
        self.unzipdir = fmpy.extract(self.path)
        self.fmu: Any = None
        self.t = 0.0
        self.k = 0

    # ---- description ----
    def _var(self, name: str) -> Any:
        return self.variables_.var(name)

    def _bounds(self, given: Sequence[float] | None, attr: str, default: float) -> list[float]:
        if given is not None:
            b = [float(v) for v in given]
            if len(b) != len(self.inputs):
                raise FmuError(f"FMU '{self.name}': u_{attr} has {len(b)} values for {len(self.inputs)} inputs")
            return b
        out = []
        for c in self.in_comps:
            if c.kind == "enum" and c.items:  # the items' range, narrowed by min/max
                lo, hi = max(c.items[0], c.lo if c.lo is not None else c.items[0]), min(c.items[-1], c.hi if c.hi is not None else c.items[-1])
                out.append(float(lo if attr == "min" else hi))
                continue
            b = c.lo if attr == "min" else c.hi
            if b is None and c.kind in ("float64", "float32"):
                v = getattr(c.var, attr, None) or (getattr(c.var.declaredType, attr, None) if getattr(c.var, "declaredType", None) is not None else None)
                b = float(v) if v not in (None, "") else None
            out.append(float(b) if b is not None else default)
        return out

    def variables(self) -> list[dict[str, Any]]:
        """Every variable of the FMU: name, causality, variability, type, unit, start value
        (a list for an array), and ``shape`` for an FMI 3 array (with the ``--param`` sizes)."""
        out = []
        for v in self.md.modelVariables:
            d = dict(
                name=v.name,
                causality=v.causality,
                variability=v.variability,
                type=v.type,
                unit=v.unit or (v.declaredType.unit if getattr(v, "declaredType", None) is not None else None),
                start=_start_value(v.type, v.start),
                description=v.description,
            )
            if getattr(v, "dimensions", None):
                try:
                    d["shape"] = list(self.variables_.shape(v))
                except FmuError:
                    d["shape"] = None
            out.append(d)
        return out

    def _component_start(self, c: Component, starts: dict[str, Any]) -> Any:
        s = starts.get(c.var.name)
        if isinstance(s, list):
            return s[c.index] if c.index < len(s) else (s[0] if len(s) == 1 else None)
        return s

    def info(self) -> SimInfo:
        """The simulator description for koopbridge plus the FMU's own under ``extra["fmu"]``
        (FMI version, units, types and start values of the inputs and outputs, every variable);
        it reaches clients in the ``info`` reply's ``extra`` object."""
        variables = self.variables()
        units = {v["name"]: v["unit"] for v in variables}
        starts = {v["name"]: v["start"] for v in variables}
        return SimInfo(
            env=self.env,
            kind="fmu",
            version=f"FMI {self.md.fmiVersion}; {self.md.modelName} {self.md.version or ''}".strip(),
            dt=self.dt,
            state_names=self.outputs,
            input_names=self.inputs,
            u_min=self.u_min,
            u_max=self.u_max,
            angle_indices=self.angle_indices,
            extra=dict(
                fmu=dict(
                    file=self.path,
                    fmi_version=self.md.fmiVersion,
                    model_name=self.md.modelName,
                    generation_tool=self.md.generationTool,
                    units=dict(inputs=[units[c.var.name] for c in self.in_comps], outputs=[units[c.var.name] for c in self.out_comps]),
                    start=dict(
                        inputs=[self._component_start(c, starts) for c in self.in_comps],
                        outputs=[self._component_start(c, starts) for c in self.out_comps],
                    ),
                    types=dict(inputs=[c.var.type for c in self.in_comps], outputs=[c.var.type for c in self.out_comps]),
                    initial=self.initial,
                    variables=variables,
                )
            ),
        )

    # ---- simulation ----
    def _logger(self, *args: Any) -> None:
        # FMI 2: (env, instanceName, status, category, message); FMI 3: (env, status, category, message)
        msg = args[-1]
        self.log.append(msg.decode("utf-8", "replace") if isinstance(msg, bytes) else str(msg))
        del self.log[:-20]

    def _instantiate(self) -> None:
        from fmpy.fmi2 import FMU2Slave

        kw = dict(
            guid=self.md.guid if not self.fmi3 else self.md.instantiationToken,
            unzipDirectory=self.unzipdir,
            modelIdentifier=self.md.coSimulation.modelIdentifier,
            instanceName="koopbridge",
        )
        try:
            if self.fmi3:
                from fmpy.fmi3 import FMU3Slave

                self.fmu = FMU3Slave(**kw)
                self.fmu.instantiate(logMessage=self._logger)
            else:
                from fmpy.fmi2 import defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
                from fmpy.logging import addLoggerProxy

                self.fmu = FMU2Slave(**kw)
                cb = fmi2CallbackFunctions()
                cb.logger = fmi2CallbackLoggerTYPE(self._logger)
                cb.allocateMemory = defaultCallbacks.allocateMemory
                cb.freeMemory = defaultCallbacks.freeMemory
                addLoggerProxy(byref(cb))
                self._callbacks = cb  # keep alive as long as the instance
                self.fmu.instantiate(callbacks=cb)
        except Exception as e:
            raise FmuError(f"FMU '{self.name}': cannot instantiate ({e}){self._last_log()}") from e

    def _last_log(self) -> str:
        return f"; the FMU said: {self.log[-1]}" if self.log else ""

    def reset(self, seed: int | None = None, x0: Sequence[float] | None = None) -> np.ndarray:
        """Re-initialises the FMU: at ``x0``, at a state drawn with ``seed`` from the
        ``x0_low``..``x0_high`` range, or (neither) at the FMU's start values. Returns x_0."""
        nx = len(self.outputs)
        if x0 is None and seed is not None:
            if self.x0_low is None or self.x0_high is None:
                raise Unsupported(f"FMU '{self.name}': a seeded reset needs an initial-state range (--x0-low/--x0-high)")
            x0 = np.random.default_rng(seed).uniform(self.x0_low, self.x0_high)
            # a draw for an integer, enumeration or Boolean variable is rounded to its nearest value
            discrete = [i for i, c in enumerate(self.init_comps) if c.kind in ("int", "enum", "bool")]
            x0[discrete] = np.round(x0[discrete])
        x0_typed = None
        if x0 is not None:
            x0 = np.asarray(x0, dtype=float).ravel()
            if x0.shape != (nx,) or not np.all(np.isfinite(x0)):
                raise InvalidInput(f"FMU '{self.name}': x0 must be {nx} finite values")
            if not self.initial:
                raise Unsupported(f"FMU '{self.name}': no initial-state variables to set x0 (--initial NAMES)")
            x0_typed = self._init.convert(x0)  # InvalidInput before the FMU is touched
        try:
            if self.fmu is None:
                self._instantiate()
            else:
                self.fmu.reset()
            self.log.clear()
            if not self.fmi3:
                self.fmu.setupExperiment(startTime=0.0)
            for acc, values in self._params:
                acc.set(self.fmu, converted=values)
            if x0_typed is not None:
                self._init.set(self.fmu, converted=x0_typed)
            if self.fmi3:
                self.fmu.enterInitializationMode(startTime=0.0)
            else:
                self.fmu.enterInitializationMode()
            self.fmu.exitInitializationMode()
            x = self._out.get(self.fmu)
        except (FmuError, InvalidInput, Unsupported):
            raise
        except Exception as e:
            self._discard()
            raise FmuError(f"FMU '{self.name}': reset failed ({e}){self._last_log()}") from e
        self.t = 0.0
        self.k = 0
        return x

    def step(self, u: Sequence[float]) -> np.ndarray:
        """Sets the inputs to ``u``, calls ``doStep`` over ``dt`` and returns the outputs."""
        if self.fmu is None:
            raise InvalidInput(f"FMU '{self.name}': not reset yet")
        u = np.asarray(u, dtype=float).ravel()
        if u.shape != (len(self.inputs),):
            raise InvalidInput(f"FMU '{self.name}': u must have {len(self.inputs)} values, got {u.size}")
        u_typed = self._in.convert(u) if len(self.inputs) else []  # InvalidInput: the FMU is untouched
        fmu = self.fmu
        try:
            if len(self.inputs):
                self._in.set(fmu, converted=u_typed)
            if self.fmi3:
                _, terminate, early, _ = fmu.doStep(self.t, self.dt)
                if terminate or early:
                    raise RuntimeError("the FMU ended the step early or asked to terminate")
            else:
                fmu.fmi2DoStep(fmu.component, self.t, self.dt, 1)
            x = self._out.get(fmu)
        except Exception as e:
            t = self.t
            self._discard()
            raise FmuError(f"FMU '{self.name}': doStep failed at t = {t:.6g} s ({e}){self._last_log()}; reset it to go on") from e
        self.k += 1
        self.t = self.k * self.dt
        return x

    def _discard(self) -> None:
        """Frees a failed instance; the next reset instantiates a fresh one."""
        fmu, self.fmu = self.fmu, None
        if fmu is not None:
            try:
                fmu.freeInstance()
            except Exception:
                pass

    def close(self) -> None:
        """Frees the instance and removes the extracted FMU."""
        if self.fmu is not None:
            try:
                self.fmu.terminate()
            except Exception:
                pass
            self._discard()
        if self.unzipdir:
            shutil.rmtree(self.unzipdir, ignore_errors=True)
            self.unzipdir = ""

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
