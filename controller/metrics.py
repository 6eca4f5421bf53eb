"""Figures of a run's commands that every loop reports the same way: simulate, replay and drive.

Pedal switches, steering reversals (the reversal-rate count of driver studies), the rates of
the commands per control update, and whether the car did what was asked: time at each actuator
limit, stalls (the reference moves, the car does not) and the verdict that a run could not
follow its reference. Pure functions of arrays; no controller, plant or bus.
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


def smoothness_of(
    time_s, steering_cmd_rad, accel_pedal_cmd, brake_pedal_cmd, *, duration_s: float | None = None
) -> dict:
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
        "steering_reversals_per_min": {
            f"{g}deg": steering_reversals(sw_deg, float(g)) / minutes for g in (1, 5)
        },
        "steering_rate_rms_radps": rate_rms(t, steering_cmd_rad),
        "accel_pedal_rate_rms_ps": rate_rms(t, accel_pedal_cmd),
        "brake_pedal_rate_rms_ps": rate_rms(t, brake_pedal_cmd),
    }


# ------------------------------------------------------------- did the car do what was asked
#: [m/s] the reference "moves" above this speed (faster than a creeping car's hold)
STALL_REF_SPEED_MPS = 0.5
#: [m/s] the car "does not" below this speed (the standstill of the wheel speeds' resolution
#: and the plant's clamp, with margin)
STALL_SPEED_MPS = 0.2
#: [s] a stall this long means the run did not follow its reference: no controller waits
#: that long to pull away (the MPC's standstill hold releases within its look-ahead, 1 s)
STALL_MAX_S = 2.0
#: [1] an actuator at its limit for more than this share of the run (and at least
#: ``LIMIT_MIN_S``) means the run asked more than the car could do: a tracking controller
#: touches a limit in a transient, it does not live there
LIMIT_MAX_SHARE = 0.2
LIMIT_MIN_S = 3.0
#: [1] relative tolerance of "at the limit" (a command clamped there equals it)
LIMIT_TOL = 0.005


def _durations(time_s: np.ndarray) -> np.ndarray:
    """Each sample's share of time [s]: until the next sample (the last: the median step)."""
    t = np.asarray(time_s, dtype=float)
    if len(t) < 2:
        return np.zeros(len(t))
    d = np.diff(t)
    return np.append(d, np.median(d))


def limit_times(
    time_s,
    steering_cmd_rad,
    accel_pedal_cmd,
    brake_pedal_cmd,
    *,
    steering_wheel_angle_max_rad: float,
    pedal_max: float = 1.0,
) -> dict:
    """Time [s] each command spent at its limit: the steering wheel at its lock (either
    side), the accelerator and the brake pedal at full travel."""
    dt = _durations(time_s)
    sw = np.abs(np.asarray(steering_cmd_rad, dtype=float))
    ap = np.asarray(accel_pedal_cmd, dtype=float)
    bp = np.asarray(brake_pedal_cmd, dtype=float)
    tol = 1.0 - LIMIT_TOL
    return {
        "steering_at_lock_s": float(dt[sw >= tol * steering_wheel_angle_max_rad].sum()),
        "accel_pedal_at_max_s": float(dt[ap >= tol * pedal_max].sum()),
        "brake_pedal_at_max_s": float(dt[bp >= tol * pedal_max].sum()),
    }


def stall_figures(time_s, speed_mps, speed_ref_mps) -> dict:
    """Stalls: stretches where the reference moves (above ``STALL_REF_SPEED_MPS``) and the car
    does not (below ``STALL_SPEED_MPS``): {total_s, longest_s, count, first_t_s}."""
    t = np.asarray(time_s, dtype=float)
    dt = _durations(t)
    on = (np.asarray(speed_ref_mps, dtype=float) > STALL_REF_SPEED_MPS) & (
        np.asarray(speed_mps, dtype=float) < STALL_SPEED_MPS
    )
    longest = run = 0.0
    count, first = 0, None
    for i in range(len(t)):
        if on[i]:
            if run == 0.0:
                count += 1
                first = float(t[i]) if first is None else first
            run += dt[i]
            longest = max(longest, run)
        else:
            run = 0.0
    return {
        "total_s": float(dt[on].sum()),
        "longest_s": float(longest),
        "count": int(count),
        "first_t_s": first,
    }


def follow_verdict(
    limits: dict, stalls: dict, duration_s: float, *, steering_wheel_angle_max_rad: float
) -> tuple[bool, list[str]]:
    """Whether a run followed its reference, and if not why, one line each: a stall longer
    than ``STALL_MAX_S``, an actuator at its limit for more than ``LIMIT_MAX_SHARE`` of the run
    (and at least ``LIMIT_MIN_S``)."""
    why = []
    if stalls["longest_s"] > STALL_MAX_S:
        why.append(
            f"the car stood still {stalls['longest_s']:.1f} s while the reference moved "
            f"(from {stalls['first_t_s']:.1f} s; {stalls['total_s']:.1f} s in all)"
        )
    names = {
        "steering_at_lock_s": f"the steering wheel sat at its "
        f"{steering_wheel_angle_max_rad:.2f} rad lock",
        "accel_pedal_at_max_s": "the accelerator was at full travel",
        "brake_pedal_at_max_s": "the brake was at full travel",
    }
    for key, text in names.items():
        s = limits[key]
        if s >= LIMIT_MIN_S and s > LIMIT_MAX_SHARE * max(duration_s, 1e-9):
            why.append(f"{text} {s:.1f} of {duration_s:.1f} s")
    return not why, why
