"""Figures of a run's commands that every loop reports the same way: simulate, replay and drive.

Pedal switches, steering reversals (the reversal-rate count of driver studies) and the rates
of the commands per control update. Pure functions of arrays; no controller, plant or bus.
"""
from __future__ import annotations

import numpy as np


def pedal_switches(accel_pedal: np.ndarray, brake_pedal: np.ndarray, deadband: float = 1e-3) -> int:
    """Throttle-to-brake and brake-to-throttle changes of the pressed pedal (a pedal
    released with the other not yet pressed continues the last one)."""
    last = None
    count = 0
    for ap, bp in zip(accel_pedal, brake_pedal):
        cur = "T" if ap > deadband else "B" if bp > deadband else None
        if cur is None:
            continue
        if last is not None and cur != last:
            count += 1
        last = cur
    return count


def steering_reversals(angle_deg, threshold_deg: float) -> int:
    """Steering reversals of at least ``threshold_deg`` in a steering-wheel angle [deg].

    The reversal-rate count of driver studies (a gap size on the steering-wheel angle):
    the signal's last extremum is tracked; a reversal is counted when the angle has come
    back from it by ``threshold_deg`` or more, and that point starts the next swing. The
    first swing of at least the threshold sets the direction and is not a reversal (a sine
    of amplitude A >= threshold over n periods from a zero crossing gives 2n).
    """
    a = np.asarray(angle_deg, dtype=float)
    if not threshold_deg > 0:
        raise ValueError(f"threshold_deg must be positive, got {threshold_deg!r}")
    if len(a) == 0:
        return 0
    count, direction = 0, 0
    lo = hi = ext = float(a[0])
    for v in a:
        v = float(v)
        if direction == 0:
            lo, hi = min(lo, v), max(hi, v)
            if v - lo >= threshold_deg:
                direction, ext = 1, v
            elif hi - v >= threshold_deg:
                direction, ext = -1, v
        elif direction > 0:
            if v > ext:
                ext = v
            elif ext - v >= threshold_deg:
                count, direction, ext = count + 1, -1, v
        else:
            if v < ext:
                ext = v
            elif v - ext >= threshold_deg:
                count, direction, ext = count + 1, 1, v
    return count


def rate_rms(time_s, signal) -> float:
    """RMS rate of a command [unit/s]: the change at each control update divided by the
    time since the previous update (the control period), over the run's updates.

    ``time_s`` and ``signal`` are the update instants and the values set there, one sample
    per control update (simulate, replay and drive alike): a command held for a period T
    and resampled every dt < T would read sqrt(T / dt) times its rate (its whole change in
    one dt, then zeros)."""
    t = np.asarray(time_s, dtype=float)
    x = np.asarray(signal, dtype=float)
    if len(t) < 2:
        return 0.0
    return float(np.sqrt(np.mean((np.diff(x) / np.diff(t)) ** 2)))


def smoothness_of(time_s, steering_cmd_rad, accel_pedal_cmd, brake_pedal_cmd, *,
                  duration_s: float | None = None) -> dict:
    """The smoothness figures of a run's COMMANDS (stable keys): steering-wheel
    reversals per minute of at least 1 and 5 deg, the steering-wheel rate RMS [rad/s] and
    the pedal rates RMS [full travel / s] (see :func:`rate_rms`: one sample per control
    update). ``duration_s``: the run's length the reversals are counted over [s] (default:
    last minus first update)."""
    t = np.asarray(time_s, dtype=float)
    span = duration_s if duration_s is not None else (t[-1] - t[0] if len(t) else 0.0)
    minutes = max(float(span) / 60.0, 1e-9)
    sw_deg = np.degrees(np.asarray(steering_cmd_rad, dtype=float))
    return {
        "steering_reversals_per_min": {f"{g}deg": steering_reversals(sw_deg, float(g)) / minutes
                                       for g in (1, 5)},
        "steering_rate_rms_radps": rate_rms(t, steering_cmd_rad),
        "accel_pedal_rate_rms_ps": rate_rms(t, accel_pedal_cmd),
        "brake_pedal_rate_rms_ps": rate_rms(t, brake_pedal_cmd),
    }
