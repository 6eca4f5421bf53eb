"""The estimator over a recording, offline: :func:`estimate_recording` feeds a canonical
recording's raw channels (e.g. the real comma2k19 minute) to :class:`Estimator`, each at its
own times; ``tools/estimate_plot.py`` plots the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hmpc.models.params import Params

from hmpc.controller.estimator.config import NXE, EstimatorConfig
from hmpc.controller.estimator.estimator import Estimator


@dataclass
class EstimateRun:
    """The estimator run over a recording (see :func:`estimate_recording`).

    Attributes:
        t_s: tick times [s]; state: (n, 7) estimate at each tick (``STATE_NAMES``);
        sigma: (n, 7) 1-sigma; stats: the estimator's per-sensor counts; events: messages fed
        per stream.
    """

    t_s: np.ndarray
    state: np.ndarray
    sigma: np.ndarray
    stats: dict
    events: dict


def _source_of(rec, channel: str) -> str:
    info = rec.meta.get("channels", {}).get(channel, {}) if isinstance(rec.meta, dict) else {}
    src = str(info.get("source", "")) if isinstance(info, dict) else ""
    return src.split(":", 1)[0] if src else ""


def estimate_recording(
    rec,
    params: Params,
    config: EstimatorConfig | None = None,
    *,
    tick_s: float = 0.02,
    gnss_latency_s: float = 0.0,
) -> EstimateRun:
    """Run the estimator over a canonical recording's raw channels, each at its own times.

    Streams (``rec.raw``, falling back to the grid when a channel has no raw samples): the four
    wheel speeds and the steering-wheel angle as CAN messages; ``yaw_rate`` (from the IMU, or
    from CAN when ingest says so) with ``accel_x`` as IMU samples; ``x``, ``y``, ``heading``,
    ``gps_speed`` as GNSS fixes. The plant input for :meth:`Estimator.predict` every ``tick_s``
    is the held steering-wheel angle and pedals. Ingest has already put every source on the
    CAN clock, so fixes are fed without latency unless ``gnss_latency_s`` > 0 (they are then
    delivered that much later than their stamp: the filter's rewind runs on real data).
    Non-finite samples are skipped.

    Raises:
        InputError: the recording lacks the GNSS position or heading (nothing to start from).
    """
    rec.require("x", "y", "heading")

    def stream(name):
        if name in rec.raw and len(rec.raw[name][0]):
            t, v = rec.raw[name]
        elif name in rec.channels:
            t, v = rec.time, rec.channels[name]
        else:
            return None
        return np.asarray(t, dtype=float), np.asarray(v, dtype=float)

    events: list[tuple[float, int, int, str]] = []  # (t_arrival, order, index, kind)
    wheels = [stream(f"wheel_speed_{w}") for w in ("fl", "fr", "rl", "rr")]
    sw = stream("steering_wheel_angle")
    yaw, ax = stream("yaw_rate"), stream("accel_x")
    gx, gy, gh, gv = stream("x"), stream("y"), stream("heading"), stream("gps_speed")
    wheels_ok = all(w is not None for w in wheels) and all(
        np.array_equal(w[0], wheels[0][0]) for w in wheels
    )
    if wheels_ok:
        events += [(t, 0, i, "wheels") for i, t in enumerate(wheels[0][0])]
    if sw is not None:
        events += [(t, 0, i, "sw") for i, t in enumerate(sw[0])]
    yaw_on_can = _source_of(rec, "yaw_rate") == "can"
    if yaw is not None:
        events += [(t, 1, i, "yaw") for i, t in enumerate(yaw[0])]
    imu_ax = (
        ax is not None
        and yaw is not None
        and np.array_equal(ax[0], yaw[0])
        and _source_of(rec, "accel_x") != "can"
    )
    events += [(t + gnss_latency_s, 2, i, "gnss") for i, t in enumerate(gx[0])]
    events.sort()
    grid = rec.time
    ap = rec.channels.get("accel_pedal", np.zeros(len(grid)))
    bp = rec.channels.get("brake_pedal", np.zeros(len(grid)))
    swg = rec.channels.get("steering_wheel_angle", np.zeros(len(grid)))
    gh_on = gh[1] if gh is not None and np.array_equal(gh[0], gx[0]) else None
    gv_on = gv[1] if gv is not None and np.array_equal(gv[0], gx[0]) else None
    gy_v = np.interp(gx[0], gy[0], gy[1]) if not np.array_equal(gy[0], gx[0]) else gy[1]

    est = Estimator(params, config)
    t_start = events[0][0] if events else float(grid[0])
    t_end = max(events[-1][0] if events else float(grid[-1]), float(grid[-1]))
    ticks = np.arange(t_start, t_end + 1e-9, tick_s)
    out_x = np.full((len(ticks), NXE), np.nan)
    out_s = np.full((len(ticks), NXE), np.nan)
    counts = {"can": 0, "imu": 0, "gnss": 0}

    def fin(v):
        return None if v is None or not math.isfinite(v) else float(v)

    k = 0
    for j, tk in enumerate(ticks):
        while k < len(events) and events[k][0] <= tk:
            t, _, i, kind = events[k]
            k += 1
            if kind == "wheels":
                ws = [w[1][i] for w in wheels]
                if all(math.isfinite(q) for q in ws):
                    est.update_can(t, wheel_speeds_mps=ws)
                    counts["can"] += 1
            elif kind == "sw":
                if math.isfinite(sw[1][i]):
                    est.update_can(t, steering_wheel_angle_rad=float(sw[1][i]))
                    counts["can"] += 1
            elif kind == "yaw":
                r = fin(yaw[1][i])
                if yaw_on_can:
                    if r is not None:
                        est.update_can(t, yaw_rate_radps=r)
                        counts["can"] += 1
                else:
                    est.update_imu(t, r, fin(ax[1][i]) if imu_ax else None)
                    counts["imu"] += 1
            else:
                t_meas = float(gx[0][i])
                x, y = fin(gx[1][i]), fin(gy_v[i])
                if x is None or y is None:
                    x = y = None
                est.update_gnss(
                    t_meas,
                    t,
                    x,
                    y,
                    fin(None if gh_on is None else gh_on[i]),
                    fin(None if gv_on is None else gv_on[i]),
                )
                counts["gnss"] += 1
        g = min(max(int(np.searchsorted(grid, tk, side="right")) - 1, 0), len(grid) - 1)
        u = (
            swg[g] if math.isfinite(swg[g]) else 0.0,
            ap[g] if math.isfinite(ap[g]) else 0.0,
            bp[g] if math.isfinite(bp[g]) else 0.0,
        )
        est.predict(tk, u)
        if est.initialized:
            out_x[j] = est._x
            out_s[j] = np.sqrt(np.maximum(np.diag(est._P), 0.0))
    return EstimateRun(ticks, out_x, out_s, est.stats, counts)
