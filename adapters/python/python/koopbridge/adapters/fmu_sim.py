"""An FMI 2.0 / 3.0 co-simulation FMU as a discrete-time simulator ``x_{k+1} = f(x_k, u_k)``
through fmpy: inputs and outputs chosen by variable name, one ``doStep`` of ``dt`` per step with
the inputs held, reset by re-initialising the FMU. A ``koopbridge.Simulator``; no networking here
(see ``fmu.py``)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from ctypes import byref, c_double, c_uint32
from typing import Any

import numpy as np

from .._native import InvalidInput, KoopbridgeError, Unsupported
from ..simulator import SimInfo


class FmuError(KoopbridgeError):
    """A problem with an FMU; the message names the FMU file and the cause."""


def _start_value(type_name: str | None, start: Any) -> Any:
    """A variable's start value as JSON: a number for numeric types, a bool for Boolean, the
    model description's text otherwise (None when there is none)."""
    if start is None:
        return None
    text = str(start).strip()
    if type_name == "Boolean":
        return text in ("true", "1")
    if type_name in ("String", "Binary", "Clock"):
        return text
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
    ``parameters``: start values to set on every reset; ``env``, ``angle_indices``: reported.
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
            raise FmuError(f"FMU '{self.name}': it has no co-simulation interface (FMI {md.fmiVersion}; model exchange only)")
        if md.fmiVersion not in ("2.0",) and not md.fmiVersion.startswith("3."):
            raise FmuError(f"FMU '{self.name}': FMI version {md.fmiVersion} is not supported (2.0 and 3.x are)")
        self.md = md
        self.fmi3 = md.fmiVersion.startswith("3.")
        self.vars = {v.name: v for v in md.modelVariables}
        if not outputs:
            raise FmuError(f"FMU '{self.name}': no output variables chosen (the state x)")
        self.inputs = list(inputs)
        self.outputs = list(outputs)
        for n in self.inputs + self.outputs + list(initial or []) + list((parameters or {}).keys()):
            self._var(n)
        for n in self.inputs + self.outputs:
            if self._var(n).type not in ("Real", "Float64", "Float32"):
                raise FmuError(f"FMU '{self.name}': variable '{n}' is of type {self._var(n).type}; only real variables can be inputs or outputs")
        for n in self.inputs:
            if self._var(n).causality not in ("input", "parameter"):
                raise FmuError(f"FMU '{self.name}': variable '{n}' has causality '{self._var(n).causality}', it cannot be an input")
        default_dt = md.defaultExperiment.stepSize if md.defaultExperiment is not None else None
        self.dt = float(dt if dt is not None else (default_dt or 0.0))
        if not (self.dt > 0 and np.isfinite(self.dt)):
            raise FmuError(f"FMU '{self.name}': no communication step given and none in its default experiment")
        if initial is None:
            settable = all(self._var(n).causality in ("input", "parameter") or getattr(self._var(n), "initial", None) in ("exact", "approx") for n in self.outputs)
            initial = list(self.outputs) if settable else []
        self.initial = list(initial)
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
        self.parameters = dict(parameters or {})
        self.env = env or md.modelName
        self.angle_indices = list(angle_indices)
        self.vr_in = [self._var(n).valueReference for n in self.inputs]
        self.vr_out = [self._var(n).valueReference for n in self.outputs]
        self._vr_in = (c_uint32 * len(self.vr_in))(*self.vr_in)
        self._vr_out = (c_uint32 * len(self.vr_out))(*self.vr_out)
        self._u_buf = (c_double * len(self.vr_in))()
        self._x_buf = (c_double * len(self.vr_out))()
        self.log: list[str] = []
        self.unzipdir = fmpy.extract(self.path)
        self.fmu: Any = None
        self.t = 0.0
        self.k = 0

    # ---- description ----
    def _var(self, name: str) -> Any:
        v = self.vars.get(name)
        if v is None:
            known = ", ".join(sorted(self.vars)[:40])
            raise FmuError(f"FMU '{self.name}': unknown variable '{name}' (known: {known})")
        return v

    def _bounds(self, given: Sequence[float] | None, attr: str, default: float) -> list[float]:
        if given is not None:
            b = [float(v) for v in given]
            if len(b) != len(self.inputs):
                raise FmuError(f"FMU '{self.name}': u_{attr} has {len(b)} values for {len(self.inputs)} inputs")
            return b
        out = []
        for n in self.inputs:
            v = getattr(self._var(n), attr, None)
            out.append(float(v) if v not in (None, "") else default)
        return out

    def variables(self) -> list[dict[str, Any]]:
        """Every variable of the FMU: name, causality, variability, type, unit, start value."""
        out = []
        for v in self.md.modelVariables:
            out.append(
                dict(
                    name=v.name,
                    causality=v.causality,
                    variability=v.variability,
                    type=v.type,
                    unit=v.unit or (v.declaredType.unit if getattr(v, "declaredType", None) is not None else None),
                    start=_start_value(v.type, v.start),
                    description=v.description,
                )
            )
        return out

    def info(self) -> SimInfo:
        """The simulator description for koopbridge plus the FMU's own under ``extra["fmu"]``
        (FMI version, units and start values of the inputs and outputs, every variable); it
        reaches clients in the ``info`` reply's ``extra`` object."""
        units = {v["name"]: v["unit"] for v in self.variables()}
        starts = {v["name"]: v["start"] for v in self.variables()}
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
                    units=dict(inputs=[units[n] for n in self.inputs], outputs=[units[n] for n in self.outputs]),
                    start=dict(inputs=[starts[n] for n in self.inputs], outputs=[starts[n] for n in self.outputs]),
                    initial=self.initial,
                    variables=self.variables(),
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

    def _set(self, names: Sequence[str], values: Sequence[float]) -> None:
        vrs = [self._var(n).valueReference for n in names]
        if self.fmi3:
            self.fmu.setFloat64(vrs, list(map(float, values)))
        else:
            self.fmu.setReal(vrs, list(map(float, values)))

    def _get(self, vrs: Sequence[int]) -> np.ndarray:
        vals = self.fmu.getFloat64(vrs) if self.fmi3 else self.fmu.getReal(vrs)
        return np.asarray(vals, dtype=float)

    def reset(self, seed: int | None = None, x0: Sequence[float] | None = None) -> np.ndarray:
        """Re-initialises the FMU: at ``x0``, at a state drawn with ``seed`` from the
        ``x0_low``..``x0_high`` range, or (neither) at the FMU's start values. Returns x_0."""
        nx = len(self.outputs)
        if x0 is None and seed is not None:
            if self.x0_low is None or self.x0_high is None:
                raise Unsupported(f"FMU '{self.name}': a seeded reset needs an initial-state range (--x0-low/--x0-high)")
            x0 = np.random.default_rng(seed).uniform(self.x0_low, self.x0_high)
        if x0 is not None:
            x0 = np.asarray(x0, dtype=float).ravel()
            if x0.shape != (nx,) or not np.all(np.isfinite(x0)):
                raise InvalidInput(f"FMU '{self.name}': x0 must be {nx} finite values")
            if not self.initial:
                raise Unsupported(f"FMU '{self.name}': no initial-state variables to set x0 (--initial NAMES)")
        try:
            if self.fmu is None:
                self._instantiate()
            else:
                self.fmu.reset()
            self.log.clear()
            if self.fmi3:
                if self.parameters:
                    self._set(list(self.parameters), list(self.parameters.values()))
                if x0 is not None:
                    self._set(self.initial, x0)
                self.fmu.enterInitializationMode(startTime=0.0)
            else:
                self.fmu.setupExperiment(startTime=0.0)
                if self.parameters:
                    self._set(list(self.parameters), list(self.parameters.values()))
                if x0 is not None:
                    self._set(self.initial, x0)
                self.fmu.enterInitializationMode()
            self.fmu.exitInitializationMode()
            x = self._get(self.vr_out)
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
        # The hot path calls the FMI functions directly with buffers made once (fmpy's
        # setReal/getReal build new ctypes arrays on every call).
        fmu, ni, no = self.fmu, len(self.vr_in), len(self.vr_out)
        try:
            if ni:
                self._u_buf[:] = u.tolist()
                if self.fmi3:
                    fmu.fmi3SetFloat64(fmu.component, self._vr_in, ni, self._u_buf, ni)
                else:
                    fmu.fmi2SetReal(fmu.component, self._vr_in, ni, self._u_buf)
            if self.fmi3:
                _, terminate, early, _ = fmu.doStep(self.t, self.dt)
                if terminate or early:
                    raise RuntimeError("the FMU ended the step early or asked to terminate")
            else:
                fmu.fmi2DoStep(fmu.component, self.t, self.dt, 1)
            if self.fmi3:
                fmu.fmi3GetFloat64(fmu.component, self._vr_out, no, self._x_buf, no)
            else:
                fmu.fmi2GetReal(fmu.component, self._vr_out, no, self._x_buf)
            x = np.array(self._x_buf[:], dtype=float)
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
