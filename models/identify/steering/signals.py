"""What the recording gives steering identification, and which of its samples to trust.

**Methods the recording supports**: the wheel-speed difference needs the four wheel speeds, the
yaw-rate fit ``yaw_rate`` and a speed, the replay ``x``, ``y``, ``heading`` and a speed; each
skipped method is named with the missing channel (``report['selection']['skipped']``), and a
recording that supports none is an InputError naming them. Without wheel speeds the speed is
``gps_speed`` with the geometry's ``nav_lever_arm_m`` (then ``v_R`` follows exactly,
:func:`~hmpc.models.identify.steering.kinematics.rear_axle_speed`), else ``speed`` or
``gps_speed`` at an unknown point on the centre line, which the yaw-rate fit places
(``fits``). The sample checks use the measured angle available (the slip check needs the
wheel speeds).

**Trustworthy samples** (:class:`SteeringIdConfig`, each threshold with its reason): moving
(front-axle speed >= ``v_min_mps``), forward gear, finite channels, no wheel slip (rear-axle
speed within ``slip_max`` of ``v cos(delta)``), longitudinal acceleration within
``accel_max_mps2`` and lateral acceleration within ``lat_accel_max_mps2`` (the tyres' linear
range), and, for the least-squares fits, no transients (steering-wheel rate below
``sw_rate_max_radps``); every excluded sample also excludes ``guard_s`` around it. When fewer
than ``MIN_FIT_SAMPLES`` pass (a fast slalom: beyond the tyres' linear range at the peaks,
steering fast in between), the fits take the samples without the transient check, else every
moving forward sample, and the map is NOT identifiable with what was let in named.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.params import Vehicle
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.stats import dilate, savgol_derivative
from hmpc.models.identify.steering.config import SteeringIdConfig
from hmpc.models.identify.steering.kinematics import (
    rear_axle_speed,
    road_wheel_angle_from_front,
    road_wheel_angle_from_yaw,
)


#: the four wheel speeds, which the wheel-speed-difference method needs
WHEEL_SPEEDS = ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr")
#: speed channels for the yaw-rate method and the replay when the wheel speeds are absent
SPEED_CHANNELS = ("speed", "gps_speed")
#: [samples] fewest samples the direct fits run on (two parameters and a blocked interval)
MIN_FIT_SAMPLES = 20


def _need(rec: Recording, *names: str) -> None:
    rec.require(*names)


@dataclass
class SteeringSignals:
    """The recording's channels for steering identification, and measurement (a).

    Attributes:
        sw: steering-wheel angle [rad]; fl, fr, rl, rr: wheel speeds [m/s] (None when absent).
        delta_a: road-wheel angle from the front wheel speeds [rad] (None without them);
            v_front: front-axle-centre speed [m/s]; v_rear: rear-axle-centre speed [m/s].
        yaw: yaw rate [rad/s], None when the recording has none.
        dt_s: sample interval [s]; b, T: wheelbase and front track [m].
        speed_source: where the speeds come from ("wheel speeds", "speed", "gps_speed");
            v_src: that channel [m/s]; speed_point_unknown: its body point is not known (the
            yaw-rate fit estimates it, ``fits._fit_yaw``); speed_note: how v_front/v_rear follow.
        skipped: method -> why the recording does not support it (named channel).
    """

    sw: np.ndarray
    fl: np.ndarray | None
    fr: np.ndarray | None
    rl: np.ndarray | None
    rr: np.ndarray | None
    delta_a: np.ndarray | None
    v_front: np.ndarray
    v_rear: np.ndarray
    yaw: np.ndarray | None
    dt_s: float
    b: float
    T: float
    speed_source: str = "wheel speeds"
    v_src: np.ndarray | None = None
    speed_point_unknown: bool = False
    speed_note: str = "front- and rear-axle speeds from the wheel speeds"
    skipped: dict = field(default_factory=dict)


@dataclass
class SampleMasks:
    """Which samples to trust (module doc): ``usable`` for the dead time and the replay,
    ``steady`` (usable and no steering transient) for the direct fits; ``excluded`` counts why
    (None: a check the channels do not allow; a sample may count under several reasons);
    ``dropped`` attributes every sample not trusted to the first reason that drops it
    (:func:`_dropped`: the counts add up to the samples not trusted); ``relaxed`` names the
    checks let go when too few samples passed them all (module doc)."""

    usable: np.ndarray
    steady: np.ndarray
    excluded: dict
    dropped: list = field(default_factory=list)
    #: what the fits let in because fewer than MIN_FIT_SAMPLES passed every check (None: all
    #: checks held)
    relaxed: str | None = None


def _dropped(
    masks: list[tuple[str, np.ndarray, float | None, str]], steady: np.ndarray
) -> list[dict]:
    """Each sample not in ``steady`` counted under the first of ``masks`` (reason, mask,
    threshold, text) that holds for it; reasons that drop nothing are left out."""
    left = ~steady
    out = []
    for reason, m, threshold, text in masks:
        n = int(np.sum(left & m))
        left &= ~m
        if n:
            out.append({"reason": reason, "samples": n, "threshold": threshold, "text": text})
    if left.any():  # nothing above: never expected; counted so that the total holds
        out.append(
            {"reason": "other", "samples": int(left.sum()), "threshold": None, "text": "other"}
        )
    return out


def dropped_text(dropped: list[dict], total: int) -> str:
    """One line: how many of ``total`` samples each reason dropped, largest first."""
    parts = [f"{d['samples']} {d['text']}" for d in sorted(dropped, key=lambda d: -d["samples"])]
    return f"dropped {sum(d['samples'] for d in dropped)} of {total}: " + (
        "; ".join(parts) if parts else "none"
    )


def steering_signals(rec: Recording, vehicle: Vehicle) -> SteeringSignals:
    """The channels steering identification uses, and which methods they support.

    Wheel-speed difference: the four wheel speeds. Yaw rate: ``yaw_rate`` and a speed (the
    rear wheel speeds, else ``gps_speed`` with the geometry's ``nav_lever_arm_m``, else
    ``speed`` or ``gps_speed`` at a point estimated with the map). Replay: ``x``, ``y``,
    ``heading`` and a speed. Raises InputError (naming the channels) when none is supported.
    """
    _need(rec, "steering_wheel_angle")
    b, T = float(vehicle.wheelbase_m), float(vehicle.track_front_m)
    sw = np.asarray(rec["steering_wheel_angle"], dtype=float)
    yaw = np.asarray(rec["yaw_rate"], dtype=float) if "yaw_rate" in rec else None
    lever = getattr(vehicle, "nav_lever_arm_m", None)
    missing_ws = next((c for c in WHEEL_SPEEDS if c not in rec), None)
    missing_pos = next((c for c in ("x", "y", "heading") if c not in rec), None)
    skipped: dict[str, str] = {}
    kw: dict = {}
    fl: np.ndarray | None
    fr: np.ndarray | None
    rl: np.ndarray | None
    rr: np.ndarray | None
    delta_a: np.ndarray | None
    if missing_ws is None:
        fl, fr, rl, rr = (np.asarray(rec[c], dtype=float) for c in WHEEL_SPEEDS)
        delta_a, v_front = road_wheel_angle_from_front(fl, fr, b, T)
        v_rear = 0.5 * (rl + rr)
        kw["v_src"] = v_rear
    else:
        fl = fr = rl = rr = delta_a = None
        skipped["wheel_speed_difference"] = (
            f"no channel '{missing_ws}' (needs the four wheel speeds)"
        )
        src = (
            "gps_speed"
            if lever is not None and yaw is not None and "gps_speed" in rec
            else next((c for c in SPEED_CHANNELS if c in rec), None)
        )
        if src is None:
            why = "no speed: no wheel speeds, no channel 'speed' and no channel 'gps_speed'"
            skipped.setdefault("yaw_rate", why)
            skipped.setdefault("position_replay", why)
            v_front = v_rear = v_src = np.full(len(sw), np.nan)
        else:
            v_src = np.asarray(rec[src], dtype=float)
            if src == "gps_speed" and lever is not None and yaw is not None:
                v_rear = rear_axle_speed(v_src, yaw, lever)
                v_front = np.hypot(v_rear, b * yaw)
                note = (
                    f"rear- and front-axle speeds from 'gps_speed' at the geometry's "
                    f"nav_lever_arm_m {list(lever)} and the yaw rate"
                )
                unknown = False
            else:
                v_front = v_rear = v_src
                unknown = True
                note = f"'{src}' at an unknown body point: " + (
                    "its distance from the rear axle is estimated with the map by the yaw-rate fit"
                    if yaw is not None
                    else "taken as the front-axle speed (no yaw rate to place it)"
                )
            kw.update(speed_source=src, v_src=v_src, speed_point_unknown=unknown, speed_note=note)
    if yaw is None:
        skipped.setdefault("yaw_rate", "no channel 'yaw_rate'")
    if missing_pos is not None:
        skipped.setdefault("position_replay", f"no channel '{missing_pos}' (needs x, y, heading)")
    if len(skipped) == 3:
        raise InputError(
            "no steering method has its channels: "
            + "; ".join(f"{m}: {why}" for m, why in skipped.items()),
            rec.meta.get("path"),
            channel=missing_ws or "yaw_rate",
        )
    return SteeringSignals(
        sw,
        fl,
        fr,
        rl,
        rr,
        delta_a,
        v_front,
        v_rear,
        yaw,
        1.0 / rec.rate_hz,
        b,
        T,
        skipped=skipped,
        **kw,
    )


def _measured_angle(sig: SteeringSignals) -> np.ndarray:
    """A measured road-wheel angle [rad] for the sample checks: from the wheel speeds, else
    from the yaw rate and the rear-axle speed (provisional), else zeros (replay only)."""
    if sig.delta_a is not None:
        return sig.delta_a
    if sig.yaw is not None:
        return road_wheel_angle_from_yaw(sig.yaw, sig.v_rear, sig.b)
    return np.where(np.isfinite(sig.v_rear), 0.0, np.nan)


def trustworthy_samples(rec: Recording, sig: SteeringSignals, cfg: SteeringIdConfig) -> SampleMasks:
    """The samples to trust (module doc), with a count per reason of exclusion (the slip check
    needs the wheel speeds: None when they are absent).

    Raises:
        InputError: fewer than MIN_FIT_SAMPLES moving forward samples.
    """
    dt, sw, v_front, v_rear = sig.dt_s, sig.sw, sig.v_front, sig.v_rear
    delta_m = _measured_angle(sig)
    finite = np.isfinite(sw) & np.isfinite(delta_m) & np.isfinite(v_rear)
    moving = finite & (np.nan_to_num(v_front) >= cfg.v_min_mps)
    slip = np.zeros(len(sw))
    if sig.delta_a is not None:
        with np.errstate(invalid="ignore"):
            slip = np.abs(v_rear - v_front * np.cos(delta_m)) / np.maximum(v_front, 1e-6)
    accel = savgol_derivative(v_rear, dt, cfg.smooth_s)
    lat = v_rear**2 * np.tan(np.nan_to_num(delta_m)) / sig.b
    sw_rate = savgol_derivative(sw, dt, cfg.smooth_s)
    reverse = np.zeros(len(sw), dtype=bool)
    if "gear" in rec:
        reverse = np.asarray([str(g) == "R" for g in rec["gear"]])
    bad_usable = ~(
        moving
        & (np.nan_to_num(slip, nan=1.0) <= cfg.slip_max)
        & (np.abs(np.nan_to_num(accel, nan=1e9)) <= cfg.accel_max_mps2)
        & (np.abs(lat) <= cfg.lat_accel_max_mps2)
        & ~reverse
    )
    if sig.yaw is not None:
        bad_usable |= ~np.isfinite(sig.yaw)
    guard = int(round(cfg.guard_s / dt))
    usable = ~dilate(bad_usable, guard)
    transient = np.abs(np.nan_to_num(sw_rate, nan=1e9)) > cfg.sw_rate_max_radps
    steady = usable & ~dilate(transient, guard)
    excluded = {
        "not_moving_or_missing": int(np.sum(~moving)),
        "wheel_slip": (
            int(np.sum(moving & (np.nan_to_num(slip, nan=1.0) > cfg.slip_max)))
            if sig.delta_a is not None
            else None
        ),
        "longitudinal_accel": int(
            np.sum(moving & (np.abs(np.nan_to_num(accel, nan=0)) > cfg.accel_max_mps2))
        ),
        "lateral_accel": int(np.sum(moving & (np.abs(lat) > cfg.lat_accel_max_mps2))),
        "reverse": int(np.sum(reverse)),
        "steering_transient": int(np.sum(usable & ~steady)),
    }
    relaxed = None
    if steady.sum() < MIN_FIT_SAMPLES:
        # too few pass every check (a fast slalom: beyond the tyres' linear range at the
        # peaks, steering fast in between): fit on fewer checks rather than not at all; the
        # caller flags the map NOT identifiable, naming what was let in
        forward = moving & ~reverse & (np.isfinite(sig.yaw) if sig.yaw is not None else True)
        for what, mask, use in (
            ("fast steering (tyre relaxation and yaw lag in the fits)", usable, usable),
            (
                "fast steering, wheel slip, hard acceleration and lateral acceleration beyond "
                f"{cfg.lat_accel_max_mps2:g} m/s^2 (side slip in the fits)",
                forward,
                forward,
            ),
        ):
            if mask.sum() >= MIN_FIT_SAMPLES:
                relaxed, steady, usable = what, mask, use
                break
    with np.errstate(invalid="ignore"):
        dropped = _dropped(
            [
                (
                    "missing",
                    ~(np.isfinite(sw) & np.isfinite(v_rear))
                    | (~np.isfinite(sig.yaw) if sig.yaw is not None else False),
                    None,
                    "with a channel missing (NaN)",
                ),
                ("reverse", reverse, None, "in reverse gear"),
                ("slow", ~moving, cfg.v_min_mps, f"slower than {cfg.v_min_mps:.3g} m/s"),
                (
                    "wheel_slip",
                    np.nan_to_num(slip, nan=1.0) > cfg.slip_max,
                    cfg.slip_max,
                    f"with wheel slip above {100 * cfg.slip_max:g}%",
                ),
                (
                    "longitudinal_accel",
                    np.abs(np.nan_to_num(accel, nan=1e9)) > cfg.accel_max_mps2,
                    cfg.accel_max_mps2,
                    f"accelerating beyond {cfg.accel_max_mps2:g} m/s^2",
                ),
                (
                    "lateral_accel",
                    ~(np.abs(lat) <= cfg.lat_accel_max_mps2),
                    cfg.lat_accel_max_mps2,
                    f"with lateral acceleration beyond {cfg.lat_accel_max_mps2:g} m/s^2",
                ),
                (
                    "guard_margin",
                    ~usable,
                    cfg.guard_s,
                    f"within {cfg.guard_s:g} s of a dropped sample",
                ),
                (
                    "steering_transient",
                    transient,
                    cfg.sw_rate_max_radps,
                    f"steering faster than {cfg.sw_rate_max_radps:.3g} rad/s",
                ),
                (
                    "transient_guard",
                    ~steady,
                    cfg.guard_s,
                    f"within {cfg.guard_s:g} s of fast steering",
                ),
            ],
            steady,
        )
    if steady.sum() < MIN_FIT_SAMPLES:
        raise InputError(
            f"only {int(steady.sum())} trustworthy steering samples of {len(sw)} "
            f"({dropped_text(dropped, len(sw))}; thresholds for a "
            f"{sig.b:g} m wheelbase, --steering-threshold overrides them): "
            "cannot identify the steering map",
            rec.meta.get("path"),
            channel="steering_wheel_angle",
        )
    return SampleMasks(usable, steady, excluded, dropped, relaxed)
