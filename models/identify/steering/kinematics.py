"""The two measurements of the road-wheel angle delta of eq. 7, from the rigid-body geometry.

Geometry (ISO 8855; the report's eq. 1 point F is the front-axle centre, moving at speed v in
the direction heading + delta, yaw rate r = v sin(delta) / b, b = wheelbase): with no tyre
slip, the front wheels at F +- T_f/2 move at ``fl, fr = |(v cos(delta) -+ r T_f/2, v sin(delta))|``
and the rear-axle centre at ``v_R = v cos(delta) = (rl + rr) / 2``. Two measurements of the
road-wheel angle delta of the virtual middle tyre follow:

(a) **front wheel-speed difference** (the report's eqs. 2-6): eq. 5 gives the turn rate
    ``omega = (fr - fl) / T_f``. Eq. 6 as printed, ``delta_t = omega / v``, is the path
    *curvature* [1/m], not an angle; the angle follows from the kinematic relation with the
    wheelbase, ``sin(delta) = b omega / v``. hmpc inverts the exact rigid-body relations above,
    ``fr^2 - fl^2 = T_f v^2 sin(2 delta) / b`` and ``fl^2 + fr^2 = 2 v^2 (1 + T_f^2 sin^2(delta) /
    (4 b^2))`` (closed form), which reduce to eqs. 5-6 with the wheelbase for small
    angles and stay exact at full lock (0.66 rad), where eq. 5 alone is 5-20% off.
(b) **yaw rate and speed**: ``tan(delta) = b r / v_R`` (= atan(L r / v) with v the rear-axle
    speed; equivalently sin(delta) = b r / v with the front-axle speed); the rear-axle speed
    follows from the speed of any body point and the yaw rate (:func:`rear_axle_speed`).

Imports numpy only.
"""

from __future__ import annotations

import numpy as np


def road_wheel_angle_from_front(
    fl_mps, fr_mps, wheelbase_m: float, track_front_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(a) Road-wheel angle [rad] and front-axle-centre speed [m/s] from the front wheel speeds.

    Exact inverse of the no-slip rigid-body relations (module doc), in closed form: with
    ``k = 2 b (fr^2 - fl^2) / (T (fl^2 + fr^2)) = sin(2 delta) / (1 + c s)``, ``c = T^2/(4 b^2)``
    and ``s = sin^2(delta)``, ``k^2 (1 + c s)^2 = 4 s (1 - s)`` is a quadratic in s whose
    smaller root belongs to |delta| < 45 deg. The angle is NaN at rest (both wheels at 0) and
    the speed 0; both are NaN where a wheel speed is NaN.
    """
    fl = np.asarray(fl_mps, dtype=float)
    fr = np.asarray(fr_mps, dtype=float)
    b, T = float(wheelbase_m), float(track_front_m)
    S, Q = fr * fr - fl * fl, fl * fl + fr * fr
    c = T * T / (4.0 * b * b)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = 2.0 * b * S / (T * Q)
        k2 = k * k
        A, B = k2 * c * c + 4.0, 2.0 * k2 * c - 4.0
        disc = np.maximum(B * B - 4.0 * A * k2, 0.0)
        sq = np.clip((-B - np.sqrt(disc)) / (2.0 * A), 0.0, 0.5)
        delta = np.sign(k) * np.arcsin(np.sqrt(sq))
        v = np.sqrt(Q / (2.0 * (1.0 + c * np.nan_to_num(sq))))
    moving = Q > 0
    return np.where(moving, delta, np.nan), np.where(np.isfinite(Q), v, np.nan)


def road_wheel_angle_from_yaw(
    yaw_rate_radps, v_rear_mps, wheelbase_m: float, yaw_bias_radps: float = 0.0
) -> np.ndarray:
    """(b) Road-wheel angle [rad] = atan(b (r - bias) / v_R), v_R the rear-axle speed [m/s]."""
    r = np.asarray(yaw_rate_radps, dtype=float) - yaw_bias_radps
    v = np.asarray(v_rear_mps, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(v > 0, np.arctan(wheelbase_m * r / v), np.nan)


def rear_axle_speed(speed_mps, yaw_rate_radps, lever_m) -> np.ndarray:
    """Rear-axle-centre speed [m/s] from the speed [m/s] of a body point at ``lever_m`` = (x, y)
    [m] (body axes from the rear-axle centre) and the yaw rate [rad/s]: with no side slip at the
    rear axle the point moves at ``(v_R - r y, r x)``, so ``v_R = r y + sqrt(v^2 - (r x)^2)``."""
    v = np.asarray(speed_mps, dtype=float)
    r = np.asarray(yaw_rate_radps, dtype=float)
    lx, ly = float(lever_m[0]), float(lever_m[1])
    return r * ly + np.sqrt(np.maximum(v * v - (r * lx) ** 2, 0.0))
