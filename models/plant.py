"""The report's hybrid plant: kinematic bicycle (eq. 1) + steering map (eq. 7) + zone models (eq. 8).

State ``s = [x_m, y_m, psi_rad, v_mps]`` in local ENU (x east, y north, psi from east,
counter-clockwise), with (x, y) the front-wheel point as in eq. 1. Input
``u = [steering_wheel_angle_rad, accel_pedal_1, brake_pedal_1]``.

    road-wheel angle  delta = offset_rad + scale * steering_wheel_angle        (eq. 7)
    x' = v cos(psi + delta),  y' = v sin(psi + delta),  psi' = v sin(delta) / b (eq. 1)
    v' = offset_z + scale_z * accel_pedal - brake_scale_z * brake_pedal       (eq. 8, zone z)

The active zone is chosen by speed with hysteresis: the plant stays in its zone while the
speed is within ``[v_min - h, v_max + h]`` and only then re-selects by speed, so noise on a
boundary cannot make it chatter. Above the last zone the last zone's model is used and
``above_last_zone`` says so. At standstill a negative acceleration holds the car at rest:
it never rolls backwards under the brake.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hmpc.models.params import Params

NX = 4  #: state size: x, y, psi, v
NU = 3  #: input size: steering-wheel angle, accel pedal, brake pedal
IX, IY, IPSI, IV = range(NX)
ISW, IAP, IBP = range(NU)


@dataclass
class StepResult:
    """One plant step: the new state, the zone used, and the acceleration applied [m/s^2]."""

    state: np.ndarray
    zone: int
    accel_mps2: float
    above_last_zone: bool


class HybridPlant:
    """Eq. 1 + eq. 7 + eq. 8 with zone hysteresis; see the module docstring.

    Args:
        params: a complete model (``Params.is_model``).
        hysteresis_mps: zone hysteresis h [m/s]; default ``params.hysteresis_mps`` or 0.25.
    """

    def __init__(self, params: Params, hysteresis_mps: float | None = None):
        if not params.is_model:
            raise ValueError("HybridPlant needs a parameter file with steering and zones")
        self.params = params
        self.wheelbase_m = float(params.vehicle.wheelbase_m)
        self.offset_rad = float(params.steering.offset_rad)
        self.scale = float(params.steering.scale)
        h = hysteresis_mps if hysteresis_mps is not None else params.hysteresis_mps
        self.hysteresis_mps = 0.25 if h is None else float(h)
        z = params.zones
        self.v_min = np.array([q.v_min_mps for q in z])
        self.v_max = np.array([q.v_max_mps for q in z])
        self.z_offset = np.array([q.offset_mps2 for q in z])
        self.z_scale = np.array([q.scale_mps2 for q in z])
        self.z_brake = np.array([q.brake_scale_mps2 for q in z])
        self.n_zones = len(z)

    # ----------------------------------------------------------------- zones
    def zone_by_speed(self, v_mps: float) -> int:
        """Zone whose (v_min, v_max] holds v (the first zone includes 0; last zone above all)."""
        i = int(np.searchsorted(self.v_max, v_mps, side="left"))
        return min(i, self.n_zones - 1)

    def select_zone(self, v_mps: float, current: int | None) -> int:
        """Zone with hysteresis: keep ``current`` while v is within its band widened by h."""
        if current is not None and 0 <= current < self.n_zones:
            lo = self.v_min[current] - self.hysteresis_mps
            hi = self.v_max[current] + self.hysteresis_mps
            if current == 0:
                lo = -np.inf
            if current == self.n_zones - 1:
                hi = np.inf
            if lo <= v_mps <= hi:
                return current
        return self.zone_by_speed(v_mps)

    # ------------------------------------------------------------- dynamics
    def road_wheel_angle(self, steering_wheel_angle_rad):
        """Eq. 7 [rad]."""
        return self.offset_rad + self.scale * np.asarray(steering_wheel_angle_rad)

    def accel(self, zone: int, accel_pedal: float, brake_pedal: float) -> float:
        """Eq. 8 with brake for ``zone`` [m/s^2]."""
        return float(self.z_offset[zone] + self.z_scale[zone] * accel_pedal
                     - self.z_brake[zone] * brake_pedal)

    def derivative(self, s: np.ndarray, u: np.ndarray, zone: int) -> np.ndarray:
        """Continuous-time ds/dt (no standstill clamp)."""
        delta = self.offset_rad + self.scale * u[ISW]
        v = s[IV]
        return np.array([v * np.cos(s[IPSI] + delta), v * np.sin(s[IPSI] + delta),
                         v * np.sin(delta) / self.wheelbase_m, self.accel(zone, u[IAP], u[IBP])])

    def step(self, s: np.ndarray, u: np.ndarray, dt_s: float, zone: int | None = None,
             accel_extra_mps2: float = 0.0) -> StepResult:
        """Advance ``dt_s`` with inputs held, zone chosen with hysteresis from ``zone``.

        ``accel_extra_mps2`` adds unmodelled acceleration (drag, grade: used by the simulator
        to conceal effects). Integration: exact in speed (piecewise-constant acceleration,
        clamped at standstill), midpoint in heading and position.
        """
        s = np.asarray(s, dtype=float)
        z = self.select_zone(float(s[IV]), zone)
        a = self.accel(z, float(u[IAP]), float(u[IBP])) + accel_extra_mps2
        v0 = max(float(s[IV]), 0.0)
        v1 = v0 + a * dt_s
        if v1 < 0.0:  # stops within the step and stays stopped: never rolls backwards
            t_move = v0 / -a if a < 0 else 0.0
            v1 = 0.0
            dist = 0.5 * v0 * t_move
            a_eff = -v0 / dt_s
        else:
            dist = 0.5 * (v0 + v1) * dt_s
            a_eff = a
        delta = self.offset_rad + self.scale * float(u[ISW])
        dpsi = dist * np.sin(delta) / self.wheelbase_m
        psi_mid = s[IPSI] + 0.5 * dpsi
        out = np.array([s[IX] + dist * np.cos(psi_mid + delta), s[IY] + dist * np.sin(psi_mid + delta),
                        s[IPSI] + dpsi, v1])
        return StepResult(out, z, a_eff, bool(s[IV] > self.v_max[-1]))

    def jacobians(self, s: np.ndarray, u: np.ndarray, zone: int) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time Jacobians (A = df/ds, B = df/du) at (s, u) in ``zone``."""
        delta = self.offset_rad + self.scale * u[ISW]
        v, psi, b = s[IV], s[IPSI], self.wheelbase_m
        c, sn = np.cos(psi + delta), np.sin(psi + delta)
        A = np.zeros((NX, NX))
        A[IX, IPSI], A[IX, IV] = -v * sn, c
        A[IY, IPSI], A[IY, IV] = v * c, sn
        A[IPSI, IV] = np.sin(delta) / b
        B = np.zeros((NX, NU))
        B[IX, ISW] = -v * sn * self.scale
        B[IY, ISW] = v * c * self.scale
        B[IPSI, ISW] = v * np.cos(delta) * self.scale / b
        B[IV, IAP] = self.z_scale[zone]
        B[IV, IBP] = -self.z_brake[zone]
        return A, B


class DelayLine:
    """A pure dead time on one signal, in whole steps of the loop period.

    Args:
        delay_s: dead time [s]; rounded to the nearest whole number of ``dt_s`` steps.
        dt_s: loop period [s].
        initial: value output until the first input has travelled through.
    """

    def __init__(self, delay_s: float, dt_s: float, initial: float = 0.0):
        self.n = max(int(round(delay_s / dt_s)), 0)
        self._buf = [float(initial)] * self.n

    def push(self, value: float) -> float:
        """Feed this step's input; return the input of ``n`` steps ago."""
        if self.n == 0:
            return float(value)
        self._buf.append(float(value))
        return self._buf.pop(0)

    def pending(self) -> list[float]:
        """Inputs still in flight, oldest first (what an MPC must predict through)."""
        return list(self._buf)
