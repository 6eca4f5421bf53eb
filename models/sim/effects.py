"""Concealed physics for the simulator: effects the report's models (eqs. 1, 7, 8) do not hold.

The ground-truth simulator (``models.sim``) lets a list of effects (the hooks of
``models.sim.effect_base.Effect``) change what the plant sees and what the sensors report.
Identification and mismatch diagnosis are tested by hiding these effects in a recording and
checking that hmpc notices them. The default run has no effects.

The named effects (``EFFECTS`` here, ``EXTRA_EFFECTS`` of ``models.sim.effects_extra``) can be
built from text, e.g. for a command line: ``parse_effect("steering_dead_time:delay_s=0.2")``.
"""

from __future__ import annotations

import math
from collections import deque

from hmpc.models.errors import InputError
from hmpc.models.constants import G_MPS2
from hmpc.models.sim.effect_base import Effect, finite_param
from hmpc.models.sim.effects_extra import EXTRA_EFFECTS


class _Delay:
    """Pure dead time in whole internal steps (rounded to the nearest step)."""

    def __init__(self, delay_s: float):
        self.delay_s = delay_s
        self._buf: deque = deque()
        self._n = 0

    def start(self, dt_s: float, initial) -> None:
        self._n = max(int(round(self.delay_s / dt_s)), 0)
        self._buf = deque([initial] * self._n)

    def push(self, value):
        if self._n == 0:
            return value
        self._buf.append(value)
        return self._buf.popleft()


class SteeringDeadTime(Effect):
    """The road wheels follow the steering wheel ``delay_s`` [s] late (pure dead time).

    Rounded to whole internal steps of the simulator (10 ms at the default rates).
    """

    name = "steering_dead_time"

    def __init__(self, delay_s: float):
        self.delay_s = finite_param("delay_s", delay_s, lo=0.0)
        self._line = _Delay(self.delay_s)
        self._started = False

    def start(self, dt_s: float, params=None) -> None:
        self._started = False
        self._dt_s = dt_s

    def steering(self, sw_rad: float, v_mps: float) -> float:
        if not self._started:  # the wheels were where the steering wheel starts
            self._line.start(self._dt_s, sw_rad)
            self._started = True
        return self._line.push(sw_rad)

    def describe(self) -> dict:
        return {"type": self.name, "delay_s": self.delay_s}


class SteeringLag(Effect):
    """The road wheels follow the steering wheel through a first-order lag ``tau_s`` [s].

    Exact discretisation for a steering-wheel angle held over each internal step.
    """

    name = "steering_lag"

    def __init__(self, tau_s: float):
        self.tau_s = finite_param("tau_s", tau_s, lo=0.0)
        self._state: float | None = None

    def start(self, dt_s: float, params=None) -> None:
        self._state = None
        self._alpha = 1.0 if self.tau_s == 0 else 1.0 - math.exp(-dt_s / self.tau_s)

    def steering(self, sw_rad: float, v_mps: float) -> float:
        if self._state is None:
            self._state = sw_rad
            return sw_rad
        out = self._state  # output during this step: the lagged angle reached so far
        self._state = out + self._alpha * (sw_rad - out)
        return out

    def describe(self) -> dict:
        return {"type": self.name, "tau_s": self.tau_s}


class SteeringCubic(Effect):
    """Rack-and-pinion nonlinearity: the road wheels follow ``sw + cubic_per_rad2 * sw^3`` [rad].

    The report (Fig. 2) sees such a nonlinearity near full lock. ``cubic_per_rad2`` [1/rad^2]:
    0.002 turns 8.4 rad at the wheel into 9.6 rad (14 % more road-wheel angle at full lock,
    0.5 % at 1.5 rad).
    """

    name = "steering_cubic"

    def __init__(self, cubic_per_rad2: float):
        self.cubic_per_rad2 = finite_param("cubic_per_rad2", cubic_per_rad2)

    def steering(self, sw_rad: float, v_mps: float) -> float:
        return sw_rad + self.cubic_per_rad2 * sw_rad**3

    def describe(self) -> dict:
        return {"type": self.name, "cubic_per_rad2": self.cubic_per_rad2}


class Understeer(Effect):
    """Understeer of a linear single-track car: the kinematic road-wheel angle delta of eq. 7
    acts as ``delta * b / (b + K v^2)`` (steady-state yaw rate v delta / (b + K v^2)).

    ``gradient_rad_per_mps2`` K [rad per m/s^2 of lateral acceleration]: passenger cars have
    0.002..0.005 (1..3 deg/g); 0.003 on a 2.65 m wheelbase loses 3 % of the yaw rate at 5 m/s
    and 10 % at 10 m/s. Needs the truth's steering map (taken from ``params`` at ``start``).
    """

    name = "understeer"

    def __init__(self, gradient_rad_per_mps2: float):
        self.gradient_rad_per_mps2 = finite_param(
            "gradient_rad_per_mps2", gradient_rad_per_mps2, lo=0.0
        )
        self._map: tuple[float, float, float] | None = None  # offset, scale, wheelbase

    def start(self, dt_s: float, params=None) -> None:
        if params is None or params.steering is None:
            raise ValueError("understeer needs the truth parameters (steering map, wheelbase)")
        self._map = (params.steering.offset_rad, params.steering.scale, params.vehicle.wheelbase_m)

    def steering(self, sw_rad: float, v_mps: float) -> float:
        assert self._map is not None  # started
        off, scale, b = self._map
        delta = (off + scale * sw_rad) * b / (b + self.gradient_rad_per_mps2 * v_mps * v_mps)
        return (delta - off) / scale

    def describe(self) -> dict:
        return {"type": self.name, "gradient_rad_per_mps2": self.gradient_rad_per_mps2}


class PedalDeadTime(Effect):
    """The powertrain and brakes act on the pedals ``delay_s`` [s] late (both pedals)."""

    name = "pedal_dead_time"

    def __init__(self, delay_s: float):
        self.delay_s = finite_param("delay_s", delay_s, lo=0.0)
        self._line = _Delay(self.delay_s)

    def start(self, dt_s: float, params=None) -> None:
        self._line.start(dt_s, (0.0, 0.0))

    def pedals(self, accel_pedal: float, brake_pedal: float) -> tuple[float, float]:
        return self._line.push((accel_pedal, brake_pedal))

    def describe(self) -> dict:
        return {"type": self.name, "delay_s": self.delay_s}


class AeroDrag(Effect):
    """Aerodynamic drag: extra acceleration ``-coeff_per_m * v^2`` [m/s^2].

    ``coeff_per_m`` = rho * Cd * A / (2 m) [1/m]; a RAV4 (Cd A ~ 0.33 * 2.6 m^2, 1600 kg,
    rho 1.2 kg/m^3) has about 3.2e-4 1/m, i.e. -0.03 m/s^2 at 10 m/s and -0.13 m/s^2 at 20 m/s.
    """

    name = "aero_drag"

    def __init__(self, coeff_per_m: float):
        self.coeff_per_m = finite_param("coeff_per_m", coeff_per_m, lo=0.0)

    def accel_extra_mps2(self, state, u) -> float:
        v = state[3]
        return -self.coeff_per_m * v * v

    def describe(self) -> dict:
        return {"type": self.name, "coeff_per_m": self.coeff_per_m}


class RoadGrade(Effect):
    """A constant road grade ``grade_rad`` [rad] (positive uphill) along the whole run.

    Adds ``-g sin(grade)`` [m/s^2] to the acceleration, raises the INS height by
    ``sin(grade)`` per metre travelled and adds the grade to the INS pitch. The INS
    accelerations stay gravity-compensated (kinematic), as a navigation-grade INS reports them.
    """

    name = "road_grade"

    def __init__(self, grade_rad: float):
        self.grade = finite_param("grade_rad", grade_rad)
        if abs(self.grade) > 0.35:  # 35 % slope: steeper than any public road
            raise ValueError(f"grade_rad must be within +-0.35 rad, got {grade_rad!r}")

    def accel_extra_mps2(self, state, u) -> float:
        return -G_MPS2 * math.sin(self.grade)

    def grade_rad(self) -> float:
        return self.grade

    def describe(self) -> dict:
        return {"type": self.name, "grade_rad": self.grade}


class WheelRadiusError(Effect):
    """The CAN wheel speeds (and the speed derived from them) read ``scale`` times the truth.

    The ECU converts wheel rotation to speed with a nominal rolling radius; tyres whose real
    radius is 1 % smaller (worn, under-inflated) make it read ``scale`` = 1/0.99 = 1.0101.
    """

    name = "wheel_radius_error"

    def __init__(self, scale: float):
        self.scale = finite_param("scale", scale, lo=0.0, lo_open=True)

    def wheel_speed_scale(self) -> float:
        return self.scale

    def describe(self) -> dict:
        return {"type": self.name, "scale": self.scale}


class ClockOffset(Effect):
    """CAN timestamps run ``can_offset_s`` [s] ahead of the INS clock (negative: behind).

    A CAN sample taken at true time t is stamped t + can_offset_s; INS stamps are true time.
    """

    name = "clock_offset"

    def __init__(self, can_offset_s: float):
        self.can_offset_s = finite_param("can_offset_s", can_offset_s)
        if abs(self.can_offset_s) > 5.0:
            raise ValueError(f"can_offset_s must be within +-5 s, got {can_offset_s!r}")

    def can_clock_offset_s(self) -> float:
        return self.can_offset_s

    def describe(self) -> dict:
        return {"type": self.name, "can_offset_s": self.can_offset_s}


#: registry name -> Effect class (constructor keyword arguments carry their units).
EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        SteeringDeadTime,
        SteeringLag,
        SteeringCubic,
        Understeer,
        PedalDeadTime,
        AeroDrag,
        RoadGrade,
        WheelRadiusError,
        ClockOffset,
    )
}


def effect_from_dict(spec: dict, *, where: str | None = None) -> Effect:
    """Build an effect from ``{"type": name, <keyword>: value, ...}`` (the ``describe()`` form).

    Raises InputError naming the key for an unknown type, an unknown keyword or a bad value.
    """
    if not isinstance(spec, dict) or "type" not in spec:
        raise InputError("an effect needs a 'type'", where, key="type")
    kind = spec["type"]
    known = {**EFFECTS, **EXTRA_EFFECTS}
    cls = known.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise InputError(
            f"unknown effect {kind!r} (known: {', '.join(sorted(known))})", where, key="type"
        )
    kwargs = {k: v for k, v in spec.items() if k != "type"}
    try:
        return cls(**kwargs)
    except TypeError:
        import inspect

        allowed = [p for p in inspect.signature(cls).parameters]
        bad = [k for k in kwargs if k not in allowed]
        key = bad[0] if bad else kind
        raise InputError(f"effect {kind!r} takes {', '.join(allowed)}", where, key=key) from None
    except ValueError as exc:
        raise InputError(str(exc), where, key=kind) from None


def parse_effect(text: str) -> Effect:
    """Build an effect from ``name:key=value[,key=value]``, e.g. ``aero_drag:coeff_per_m=3e-4``.

    Raises InputError (one line naming the effect) for malformed text.
    """
    name, _, rest = str(text).partition(":")
    spec: dict = {"type": name.strip()}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq:
            raise InputError(f"expected key=value in effect '{text}'", None, key=item)
        try:
            spec[key.strip()] = float(val)
        except ValueError:
            raise InputError(
                f"value {val!r} is not a number in effect '{text}'", None, key=key.strip()
            ) from None
    return effect_from_dict(spec, where=None)
