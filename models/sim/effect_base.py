"""The base of the simulator's concealed physics: the :class:`Effect` hooks, each a no-op here,
and what the named effects share (standard gravity, the check of a parameter value).

The ground-truth simulator (``models.sim``) runs the hybrid plant of ``models.plant`` and lets
a list of :class:`Effect` objects change what the plant sees and what the sensors report. The
named effects live in ``models.sim.effects`` and ``models.sim.effects_extra``.

Hooks (each a no-op in the base class; a subclass overrides only what it changes):

- ``start(dt_s, params)``: reset state before a run (the simulator calls it, so a list of
  effects can be reused and a seeded run is repeatable). ``dt_s`` is the plant's internal
  step [s]; ``params`` the truth (``models.params.Params``).
- ``steering(sw_rad, v_mps)``: the steering-wheel angle the road wheels follow, before eq. 7,
  called once per internal step with the measured steering-wheel angle [rad] and speed [m/s].
- ``pedals(accel_pedal, brake_pedal)``: the pedals the powertrain acts on (fractions 0..1),
  called once per internal step with the measured pedal positions.
- ``accel_extra_mps2(state, u)``: extra longitudinal acceleration [m/s^2] added to eq. 8, given
  the plant state ``(x_m, y_m, psi_rad, v_mps)`` and the effective inputs
  ``(steering_wheel_angle_rad, accel_pedal, brake_pedal)``.
- ``grade_rad()``: road grade [rad] (positive uphill) seen by the INS (pitch, height).
- ``wheel_speed_scale()``: factor on the CAN wheel speeds (and the speed derived from them).
- ``can_clock_offset_s()``: CAN timestamps minus INS timestamps [s] in the recording.

Effects compose: steering and pedal hooks are chained in list order, accelerations add,
grades add, wheel-speed scales multiply, clock offsets add.
"""

from __future__ import annotations

import math


class Effect:
    """Base class: every hook leaves the plant and the sensors unchanged."""

    #: registry name (``models.sim.effects.EFFECTS``, ``models.sim.effects_extra.EXTRA_EFFECTS``)
    name = "effect"

    def start(self, dt_s: float, params=None) -> None:
        """Reset internal state before a run with internal step ``dt_s`` [s] on truth ``params``."""

    def steering(self, sw_rad: float, v_mps: float) -> float:
        """Steering-wheel angle [rad] the road wheels follow (before eq. 7) at speed ``v_mps``."""
        return sw_rad

    def pedals(self, accel_pedal: float, brake_pedal: float) -> tuple[float, float]:
        """Pedal positions (0..1) the powertrain acts on."""
        return accel_pedal, brake_pedal

    def accel_extra_mps2(self, state, u) -> float:
        """Extra longitudinal acceleration [m/s^2] given state (x, y, psi, v) and inputs u."""
        return 0.0

    def grade_rad(self) -> float:
        """Road grade [rad], positive uphill."""
        return 0.0

    def wheel_speed_scale(self) -> float:
        """Factor on the wheel speeds reported on CAN (1 = exact)."""
        return 1.0

    def can_clock_offset_s(self) -> float:
        """CAN timestamps minus INS timestamps [s] (CAN time = true time + offset)."""
        return 0.0

    def describe(self) -> dict:
        """A JSON-friendly description: ``{"type": name, <parameter with unit>: value, ...}``."""
        return {"type": self.name}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.describe().items() if k != "type")
        return f"{type(self).__name__}({args})"


def finite_param(
    name: str, value: float, *, lo: float | None = None, lo_open: bool = False
) -> float:
    """``value`` as a float; ValueError naming ``name`` unless finite and at least ``lo``
    (above it with ``lo_open``)."""
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        rel = ">" if lo_open else ">="
        raise ValueError(f"{name} must be {rel} {lo}, got {value!r}")
    return v
