"""More concealed physics for the ground-truth simulator (the diagnosis benchmark's).

Kept apart from ``models.sim.effects`` (same :class:`~hmpc.models.sim.effect_base.Effect` hooks):

- :class:`IdleCreep`: a speed-regulating idle torque (torque converter at idle);
- :class:`HillyRoad`: a road grade that varies with the distance travelled (the constant
  :class:`~hmpc.models.sim.effects.RoadGrade` is confounded with the zone offsets of eq. 8, a
  real road's is not). The simulator's INS sees a constant grade only; the diagnosis test data
  (``models.diagnose.testdata``) rewrites ``z`` and ``pitch`` from :meth:`HillyRoad.grade_at`;
- :class:`MassChange`: the car's mass changes at a given time (a trailer, passengers): the
  pedal authority is scaled by ``factor`` from then on. Not in the diagnosis catalogue on
  purpose: it must be reported as unexplained.
"""

from __future__ import annotations

import math

from hmpc.models.constants import G_MPS2
from hmpc.models.sim.effect_base import Effect, finite_param


class IdleCreep(Effect):
    """Idle torque that regulates the speed towards ``creep_speed_mps`` with the throttle released.

    Extra acceleration ``accel_mps2 * max(0, 1 - v / creep_speed_mps)`` [m/s^2] while the
    accelerator pedal is below 0.01 (a torque converter at idle: full creep torque at rest,
    none at the creep speed). Typical automatic cars: 0.3..0.8 m/s^2, 1.5..3 m/s.
    """

    name = "idle_creep"

    def __init__(self, accel_mps2: float, creep_speed_mps: float):
        self.accel_mps2 = finite_param("accel_mps2", accel_mps2, lo=0.0)
        self.creep_speed_mps = finite_param(
            "creep_speed_mps", creep_speed_mps, lo=0.0, lo_open=True
        )

    def accel_extra_mps2(self, state, u) -> float:
        if u[1] >= 0.01:
            return 0.0
        return self.accel_mps2 * max(0.0, 1.0 - float(state[3]) / self.creep_speed_mps)

    def describe(self) -> dict:
        return {
            "type": self.name,
            "accel_mps2": self.accel_mps2,
            "creep_speed_mps": self.creep_speed_mps,
        }


class HillyRoad(Effect):
    """Road grade ``amplitude_rad * sin(2 pi s / wavelength_m)`` [rad] at distance s [m] travelled.

    Adds ``-g sin(grade)`` [m/s^2] to the acceleration. The distance is integrated from the
    plant's speed, one call per internal step.
    """

    name = "hilly_road"

    def __init__(self, amplitude_rad: float, wavelength_m: float):
        self.amplitude_rad = finite_param("amplitude_rad", amplitude_rad)
        if abs(self.amplitude_rad) > 0.2:  # 20 % grades are the steepest public roads
            raise ValueError(f"amplitude_rad must be within +-0.2 rad, got {amplitude_rad!r}")
        self.wavelength_m = finite_param("wavelength_m", wavelength_m, lo=1.0)
        self._s_m = 0.0
        self._dt_s = 0.01

    def start(self, dt_s: float, params=None) -> None:
        self._s_m = 0.0
        self._dt_s = dt_s

    def grade_at(self, s_m):
        """Grade [rad] at distance ``s_m`` [m] (scalar or array)."""
        import numpy as np

        return self.amplitude_rad * np.sin(2.0 * math.pi * np.asarray(s_m) / self.wavelength_m)

    def accel_extra_mps2(self, state, u) -> float:
        g = self.amplitude_rad * math.sin(2.0 * math.pi * self._s_m / self.wavelength_m)
        self._s_m += max(float(state[3]), 0.0) * self._dt_s
        return -G_MPS2 * math.sin(g)

    def describe(self) -> dict:
        return {
            "type": self.name,
            "amplitude_rad": self.amplitude_rad,
            "wavelength_m": self.wavelength_m,
        }


class MassChange(Effect):
    """From ``at_s`` [s] of run time on, the pedals act with ``factor`` times their authority
    (mass times 1/factor for the powertrain and brake forces)."""

    name = "mass_change"

    def __init__(self, at_s: float, factor: float):
        self.at_s = finite_param("at_s", at_s, lo=0.0)
        self.factor = finite_param("factor", factor, lo=0.0, lo_open=True)
        self._k = 0
        self._dt_s = 0.01

    def start(self, dt_s: float, params=None) -> None:
        self._k = 0
        self._dt_s = dt_s

    def pedals(self, accel_pedal: float, brake_pedal: float) -> tuple[float, float]:
        t = self._k * self._dt_s
        self._k += 1
        if t < self.at_s:
            return accel_pedal, brake_pedal
        return accel_pedal * self.factor, brake_pedal * self.factor

    def describe(self) -> dict:
        return {"type": self.name, "at_s": self.at_s, "factor": self.factor}


#: the effects of this module by name, for ``models.sim.effects.effect_from_dict`` and
#: ``parse_effect`` (e.g. ``idle_creep:accel_mps2=0.5,creep_speed_mps=2``)
EXTRA_EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls for cls in (IdleCreep, HillyRoad, MassChange)
}
