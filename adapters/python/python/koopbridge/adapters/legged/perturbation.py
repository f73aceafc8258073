"""A legged simulator's episode perturbation (``reset(..., perturbation={...})``, PROTOCOL.md
"reset"): the body's mass scaled (Go2: trunk, G1: torso; its inertia with it), the feet's sliding
friction scaled, and a push (a change of the base's horizontal velocity at one step); every
reset restores the nominal robot first, so a perturbation lasts one episode."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..._native import InvalidInput

__all__ = ["Perturbation", "Perturber"]

KEYS = {"mass_scale", "friction_scale", "push"}


@dataclass(frozen=True)
class Perturbation:
    """``mass_scale``/``friction_scale``: factors (> 0; 1 = nominal); ``push``: ``(step,
    (dvx, dvy))`` — right before integrating step ``step`` the base's world-frame horizontal
    velocity changes by ``(dvx, dvy)`` m/s."""

    mass_scale: float = 1.0
    friction_scale: float = 1.0
    push: tuple[int, tuple[float, float]] | None = None

    @staticmethod
    def from_json(d: dict[str, Any] | None) -> Perturbation:
        """The perturbation of the reset request's JSON object (``None``: nominal);
        ``InvalidInput`` naming a bad key or value."""
        if d is None:
            return Perturbation()
        if not isinstance(d, dict) or set(d) - KEYS:
            raise InvalidInput(f"perturbation: unknown keys {sorted(set(d) - KEYS) if isinstance(d, dict) else d!r} (known: {sorted(KEYS)})")

        def scale(k: str) -> float:
            v = d.get(k)
            if v is None:
                return 1.0
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidInput(f"perturbation.{k} must be a finite number > 0, got {v!r}")
            return float(v)

        push = None
        if d.get("push") is not None:
            p = d["push"]
            try:
                step, (vx, vy) = int(p["step"]), (float(p["velocity"][0]), float(p["velocity"][1]))
            except (KeyError, TypeError, ValueError, IndexError) as e:
                raise InvalidInput(f"perturbation.push must be {{step, velocity: [vx, vy]}}, got {p!r}") from e
            if step < 0 or not (math.isfinite(vx) and math.isfinite(vy)):
                raise InvalidInput(f"perturbation.push: step >= 0 and a finite velocity needed, got {p!r}")
            push = (step, (vx, vy))
        return Perturbation(scale("mass_scale"), scale("friction_scale"), push)


class Perturber:
    """Applies perturbations to one MuJoCo model: ``mass_body`` (a body id) and ``feet`` (geom
    ids) are what it scales; the nominal values are kept at construction."""

    def __init__(self, model: Any, mass_body: int, feet: list[int]):
        self.model, self.mass_body, self.feet = model, int(mass_body), list(feet)
        self._mass = float(model.body_mass[self.mass_body])
        self._inertia = np.array(model.body_inertia[self.mass_body], dtype=np.float64)
        self._friction = np.array(model.geom_friction[self.feet, 0], dtype=np.float64)
        self.current = Perturbation()

    def apply(self, p: Perturbation) -> None:
        """The nominal robot scaled by ``p`` (mass and inertia together: the same shape, heavier)."""
        m = self.model
        m.body_mass[self.mass_body] = self._mass * p.mass_scale
        m.body_inertia[self.mass_body] = self._inertia * p.mass_scale
        m.geom_friction[self.feet, 0] = self._friction * p.friction_scale
        self.current = p

    def push_now(self, k: int) -> tuple[float, float] | None:
        """The push to apply before integrating step ``k``, if any."""
        p = self.current.push
        return p[1] if p is not None and p[0] == k else None
