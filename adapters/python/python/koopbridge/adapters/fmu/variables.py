"""FMI variables as the float64 components of the FMU adapter's vectors: which variables can be
served and why not, FMI 3 arrays expanded into elements (``y[0]``, ``M[0,1]``), and reading and
writing them through the FMI getter/setter of their own type with conversion and range checks."""

from __future__ import annotations

import ctypes
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..._native import InvalidInput, KoopbridgeError

__all__ = ["INTEGER_TOLERANCE", "Accessor", "Component", "FmuError", "Variables"]

INTEGER_TOLERANCE = 1e-9
"""How far from an integer (or from 0/1 for a Boolean) a float64 may be and still be accepted;
it is then rounded. Anything farther is refused (never silently rounded)."""

_FLOAT32_MAX = float(np.finfo(np.float32).max)

# FMI type -> (kind, FMI 2 function suffix, FMI 3 function suffix, ctypes type for FMI 2, for FMI 3)
_TYPES: dict[str, tuple[str, str, str, Any, Any]] = {
    "Real": ("float64", "Real", "", ctypes.c_double, None),
    "Integer": ("int", "Integer", "", ctypes.c_int, None),
    "Enumeration": ("enum", "Integer", "Int64", ctypes.c_int, ctypes.c_int64),
    "Boolean": ("bool", "Boolean", "Boolean", ctypes.c_int, ctypes.c_bool),
    "Float64": ("float64", "", "Float64", None, ctypes.c_double),
    "Float32": ("float32", "", "Float32", None, ctypes.c_float),
    "Int8": ("int", "", "Int8", None, ctypes.c_int8),
    "UInt8": ("int", "", "UInt8", None, ctypes.c_uint8),
    "Int16": ("int", "", "Int16", None, ctypes.c_int16),
    "UInt16": ("int", "", "UInt16", None, ctypes.c_uint16),
    "Int32": ("int", "", "Int32", None, ctypes.c_int32),
    "UInt32": ("int", "", "UInt32", None, ctypes.c_uint32),
    "Int64": ("int", "", "Int64", None, ctypes.c_int64),
    "UInt64": ("int", "", "UInt64", None, ctypes.c_uint64),
}
_INT_RANGE = {
    "Integer": (-(2**31), 2**31 - 1),
    "Enumeration": (-(2**63), 2**63 - 1),
    "Int8": (-128, 127),
    "UInt8": (0, 255),
    "Int16": (-(2**15), 2**15 - 1),
    "UInt16": (0, 2**16 - 1),
    "Int32": (-(2**31), 2**31 - 1),
    "UInt32": (0, 2**32 - 1),
    "Int64": (-(2**63), 2**63 - 1),
    "UInt64": (0, 2**64 - 1),
}
_ELEMENT = re.compile(r"^(.+)\[\s*(\d+(?:\s*,\s*\d+)*)\s*\]$")


class FmuError(KoopbridgeError):
    """A problem with an FMU; the message names the FMU file and the cause."""


@dataclass(frozen=True)
class Component:
    """One float64 of a vector: a scalar variable or one element of an FMI 3 array variable.

    ``name``: ``x``, ``y[1]`` or ``M[0,1]`` (zero-based, row-major); ``var``: fmpy's
    ``ModelVariable``; ``index``: the element's flat (row-major) index, 0 for a scalar;
    ``kind``: ``float64``, ``float32``, ``int``, ``enum`` or ``bool``; ``lo``/``hi``: the
    accepted range of values set (the type's range intersected with the variable's min/max;
    None for no bound); ``items``: an enumeration's item values."""

    name: str
    var: Any
    index: int = 0
    kind: str = "float64"
    lo: float | int | None = None
    hi: float | int | None = None
    items: tuple[int, ...] = field(default=())

    def convert(self, value: float, fmu_name: str, role: str) -> Any:
        """``value`` (a float64 from the wire) as the Python value of this component's FMI type,
        or ``InvalidInput`` naming the FMU, the component and the value when it cannot be
        represented: integers and enumerations within ``INTEGER_TOLERANCE`` of an integer,
        Booleans 0 or 1, all within the range; Float64 values pass unchanged."""
        v = float(value)
        if self.kind == "float64":
            return v
        why = _refusal(self, v)
        if why:
            raise InvalidInput(f"FMU '{fmu_name}': {role} '{self.name}' ({self.var.type}) cannot take {value!r}: {why}")
        if self.kind == "float32":
            return v
        r = round(v)
        return bool(r) if self.kind == "bool" else int(r)


def _refusal(c: Component, v: float) -> str:
    """Why ``v`` cannot be set on ``c`` ('' when it can)."""
    if not math.isfinite(v):
        return "not a finite number"
    if c.kind == "float32":
        if abs(v) > _FLOAT32_MAX:
            return "outside the Float32 range"
        x: float | int = v
    else:
        x = round(v)
        if abs(v - x) > INTEGER_TOLERANCE:
            return "not an integer" if c.kind != "bool" else "a Boolean is 0 or 1"
    if c.kind == "bool":
        return "" if x in (0, 1) else "a Boolean is 0 or 1"
    if c.lo is not None and x < c.lo or c.hi is not None and x > c.hi:
        return f"outside {_fmt(c.lo)}..{_fmt(c.hi)}"
    if c.items and x not in c.items:
        return f"not one of the enumeration's values {list(c.items)}"
    return ""


def _fmt(b: float | None) -> str:
    return "" if b is None else str(b)


def _attr(var: Any, name: str) -> str | None:
    v = getattr(var, name, None)
    if v in (None, "") and getattr(var, "declaredType", None) is not None:
        v = getattr(var.declaredType, name, None)
    return None if v in (None, "") else str(v)


class Variables:
    """The variables of a model description, resolved to ``Component`` lists with the reasons
    why a variable cannot be served (raised as ``FmuError`` when the adapter starts).

    ``parameters``: the ``--param`` values, which may set FMI 3 structural parameters and so
    the sizes of arrays."""

    def __init__(self, md: Any, fmu_name: str, parameters: Mapping[str, float], path: str | None = None) -> None:
        self.md = md
        self.xml_bounds = _xml_bounds(path) if path and md.fmiVersion.startswith("3.") else {}
        self.fmu_name = fmu_name
        self.fmi3 = md.fmiVersion.startswith("3.")
        self.by_name = {v.name: v for v in md.modelVariables}
        self.by_vr = {v.valueReference: v for v in md.modelVariables}
        self.parameters = dict(parameters)

    def error(self, msg: str) -> FmuError:
        """An ``FmuError`` naming the FMU."""
        return FmuError(f"FMU '{self.fmu_name}': {msg}")

    def var(self, name: str) -> Any:
        """The variable called ``name`` (``FmuError`` listing known names if there is none)."""
        v = self.by_name.get(name)
        if v is None:
            known = ", ".join(sorted(self.by_name)[:40])
            raise self.error(f"unknown variable '{name}' (known: {known})")
        return v

    def shape(self, var: Any) -> tuple[int, ...]:
        """The shape of an FMI 3 array variable (``()`` for a scalar): fixed dimensions, or the
        ``--param`` value or start value of the structural parameter that sizes it."""
        shape = []
        for d in getattr(var, "dimensions", []) or []:
            if d.start is not None:
                shape.append(int(d.start))
                continue
            size_var = self.by_vr.get(d.valueReference)
            value = None
            if size_var is not None:
                value = self.parameters.get(size_var.name, size_var.start)
            try:
                n = float(value)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                n = math.nan
            if not (math.isfinite(n) and n >= 0 and n.is_integer()):
                who = f"'{size_var.name}'" if size_var is not None else f"value reference {d.valueReference}"
                raise self.error(f"the size of array '{var.name}' is unknown (its dimension {who} has no usable value: {value!r})")
            shape.append(int(n))
        return tuple(shape)

    def component(self, var: Any, index: int, name: str) -> Component:
        """The component ``name`` (element ``index``) of ``var``, with its conversion range."""
        if var.type not in _TYPES:
            raise self.error(f"variable '{var.name}' is of type {var.type}, which cannot be served as a number")
        kind = _TYPES[var.type][0]
        lo_t, hi_t = _INT_RANGE.get(var.type, (None, None))
        if kind == "bool":
            lo_t, hi_t = 0, 1
        num = int if kind in ("int", "enum", "bool") else float
        lo_s, hi_s = _attr(var, "min"), _attr(var, "max")
        if var.name in self.xml_bounds:  # fmpy 0.3 does not read min/max of UInt variables
            lo_s = lo_s if lo_s is not None else self.xml_bounds[var.name][0]
            hi_s = hi_s if hi_s is not None else self.xml_bounds[var.name][1]
        lo = num(float(lo_s)) if lo_s is not None and kind != "bool" else lo_t
        hi = num(float(hi_s)) if hi_s is not None and kind != "bool" else hi_t
        if lo_t is not None and lo is not None:
            lo = max(lo, lo_t)
        if hi_t is not None and hi is not None:
            hi = min(hi, hi_t)
        items: tuple[int, ...] = ()
        if kind == "enum" and getattr(var, "declaredType", None) is not None:
            items = tuple(sorted(int(i.value) for i in var.declaredType.items if i.value is not None))
        return Component(name=name, var=var, index=index, kind=kind, lo=lo, hi=hi, items=items)

    def expand(self, name: str) -> list[Component]:
        """The components a name stands for: a scalar variable, every element of an array
        variable (row-major), or one element ``base[i]`` / ``base[i,j]`` (zero-based)."""
        if name in self.by_name:
            var = self.by_name[name]
            shape = self.shape(var) if self.fmi3 else ()
            if not shape:
                return [self.component(var, 0, name)]
            return [self.component(var, k, f"{name}[{','.join(map(str, idx))}]") for k, idx in enumerate(np.ndindex(*shape))]
        m = _ELEMENT.match(name)
        if m is None or m.group(1) not in self.by_name:
            self.var(name)  # raises: unknown
        base = self.by_name[m.group(1)]  # type: ignore[union-attr]
        idx = tuple(int(i) for i in m.group(2).split(","))  # type: ignore[union-attr]
        shape = self.shape(base) if self.fmi3 else ()
        if not shape:
            raise self.error(f"'{name}': variable '{base.name}' is not an array")
        if len(idx) != len(shape) or any(i >= n for i, n in zip(idx, shape, strict=True)):
            raise self.error(f"'{name}': index out of range for '{base.name}' of shape {list(shape)} (indices start at 0)")
        flat = int(np.ravel_multi_index(idx, shape))
        return [self.component(base, flat, f"{base.name}[{','.join(map(str, idx))}]")]

    def resolve(self, names: Sequence[str], role: str) -> list[Component]:
        """The components of ``names`` for ``role`` (``input``, ``output``, ``initial`` or
        ``parameter``); ``FmuError`` with the reason for one that cannot play it."""
        comps = [c for n in names for c in self.expand(n)]
        for c in comps:
            v = c.var
            if role == "input" and not (v.causality == "input" or (v.causality == "parameter" and v.variability == "tunable")):
                if v.causality == "parameter":
                    raise self.error(
                        f"variable '{c.name}' is a {v.variability} parameter; it cannot be set while stepping, so it cannot be an input (inputs and tunable parameters can)"
                    )
                raise self.error(f"variable '{c.name}' has causality '{v.causality}', it cannot be an input")
            if role in ("initial", "parameter") and not settable_before_init(v):
                raise self.error(
                    f"variable '{c.name}' (causality '{v.causality}', variability '{v.variability}', initial '{v.initial}') cannot be set before initialisation, so it cannot be an {role} variable"
                )
        if role != "output":
            self._whole_arrays(comps, role)
        return comps

    def _whole_arrays(self, comps: Sequence[Component], role: str) -> None:
        """FMI 3 sets an array in one call: a set role needs every element of an array once."""
        seen: dict[str, list[int]] = {}
        for c in comps:
            seen.setdefault(c.var.name, []).append(c.index)
        for name, idx in seen.items():
            size = int(np.prod(self.shape(self.by_name[name]))) if self.fmi3 else 1
            if sorted(idx) != list(range(size)):
                raise self.error(f"{role} variable '{name}' must be given whole and once (FMI sets all {size} elements of an array together; name it '{name}')")


def _xml_bounds(path: str) -> dict[str, tuple[str | None, str | None]]:
    """min/max of the FMI 3 UInt variables, read from the FMU's modelDescription.xml ({} if unreadable)."""
    import xml.etree.ElementTree as ET
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            root = ET.fromstring(z.read("modelDescription.xml"))
    except (OSError, KeyError, zipfile.BadZipFile, ET.ParseError):
        return {}
    out = {}
    for e in root.iter():
        if e.tag.startswith("UInt") and e.get("name") is not None:
            out[e.get("name")] = (e.get("min"), e.get("max"))
    return out


def _total(vars_: Mapping[int, tuple[int, int]]) -> int:
    """The number of values of the variables (value reference -> (offset, size)) so far."""
    return sum(size for _, size in vars_.values())


def settable_before_init(var: Any) -> bool:
    """Whether ``var`` may be set between instantiation and the end of initialisation."""
    if var.variability == "constant" or var.causality == "independent":
        return False
    return var.causality in ("input", "parameter", "structuralParameter") or var.initial in ("exact", "approx")


class Accessor:
    """Gets or sets a fixed list of components through the FMI getters/setters of their types
    (``fmi2GetInteger``, ``fmi3GetUInt8``, ...), with the value-reference arrays and buffers made
    once; whole arrays are read and the requested elements picked."""

    def __init__(self, comps: Sequence[Component], variables: Variables, role: str) -> None:
        self.comps = list(comps)
        self.fmi3 = variables.fmi3
        self.fmu_name = variables.fmu_name
        self.role = role
        self.n = len(self.comps)
        groups: dict[str, dict[str, Any]] = {}  # one per FMI function suffix
        for pos, c in enumerate(self.comps):
            _, s2, s3, t2, t3 = _TYPES[c.var.type]
            suffix, ctype = (s3, t3) if self.fmi3 else (s2, t2)
            g = groups.setdefault(suffix, dict(ctype=ctype, vars={}, pos=[], at=[], comps=[]))
            if c.var.valueReference not in g["vars"]:
                size = int(np.prod(variables.shape(c.var))) if self.fmi3 else 1
                g["vars"][c.var.valueReference] = (_total(g["vars"]), size)
            g["pos"].append(pos)
            g["at"].append(g["vars"][c.var.valueReference][0] + c.index)
            g["comps"].append(c)
        # (suffix, vr array, number of vrs, number of values, buffer, positions, buffer offsets, comps)
        self._plan = []
        for suffix, g in groups.items():
            vrs = list(g["vars"])
            total = _total(g["vars"])
            self._plan.append((suffix, (ctypes.c_uint32 * len(vrs))(*vrs), len(vrs), total, (g["ctype"] * total)(), g["pos"], g["at"], g["comps"]))

    def _fn(self, fmu: Any, op: str, suffix: str) -> Any:
        return getattr(fmu, f"fmi{3 if self.fmi3 else 2}{op}{suffix}")

    def get(self, fmu: Any) -> np.ndarray:
        """The components' current values as float64."""
        out = np.empty(self.n)
        for suffix, vrs, nvr, total, buf, pos, offsets, _ in self._plan:
            if self.fmi3:
                self._fn(fmu, "Get", suffix)(fmu.component, vrs, nvr, buf, total)
            else:
                self._fn(fmu, "Get", suffix)(fmu.component, vrs, nvr, buf)
            for p, o in zip(pos, offsets, strict=True):
                out[p] = float(buf[o])
        return out

    def convert(self, values: Sequence[float]) -> list[list[Any]]:
        """The values as the FMI types' Python values, group by group (``InvalidInput`` naming
        the component and the value when one cannot be represented); nothing is set."""
        vals = list(map(float, values))
        out = []
        for _, _, _, total, _, pos, offsets, comps in self._plan:
            row: list[Any] = [0] * total
            for p, o, c in zip(pos, offsets, comps, strict=True):
                row[o] = c.convert(vals[p], self.fmu_name, self.role)
            out.append(row)
        return out

    def set(self, fmu: Any, values: Sequence[float] | None = None, converted: list[list[Any]] | None = None) -> None:
        """Sets the components to ``values`` (every value checked before any is set), or to
        values already ``convert``-ed."""
        rows = converted if converted is not None else self.convert(values or [])
        for (suffix, vrs, nvr, total, buf, *_), row in zip(self._plan, rows, strict=True):
            buf[:] = row
            if self.fmi3:
                self._fn(fmu, "Set", suffix)(fmu.component, vrs, nvr, buf, total)
            else:
                self._fn(fmu, "Set", suffix)(fmu.component, vrs, nvr, buf)
