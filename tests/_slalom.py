"""Hand-built recordings of a kinematic car (bicycle model, rear-axle reference) for the
diagnosis's tests of what a recording supports and of its sensor pairs: a slalom or a straight
run, with four wheel speeds (0.01 km/h steps), a gyro, an accelerometer and optionally pedals
and an INS; each sensor error is set by a keyword (an IMU turned about the vertical, an
accelerometer's filter lag or its zero-phase smoothing, a per-side rolling radius, an effective
track, a steering dead time).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from hmpc.models.logs.recording import Recording

WHEELBASE_M = 2.65
TRACK_M = 1.6
SCALE = 1.0 / 16.0  #: road-wheel angle per steering-wheel angle
KMH_STEP = 0.01 / 3.6  #: wheel-speed step [m/s]


def drive(
    duration_s: float = 20.0,
    rate_hz: float = 50.0,
    *,
    speed_mps: float = 12.0,
    speed_swing_mps: float = 3.0,
    speed_ripple_mps: float = 0.0,
    sw_amp_rad: float = 1.2,
    sw_period_s: float = 4.0,
    straight: bool = False,
    pedals: bool = False,
    ins: bool = False,
    imu_yaw_rad: float = 0.0,
    accel_tau_s: float = 0.0,
    accel_smooth_s: float = 0.0,
    side_ratio: float = 0.0,
    track_scale: float = 1.0,
    steer_delay_s: float = 0.0,
    seed: int = 0,
    path: str = "slalom.csv",
) -> Recording:
    """A recording of the car (see the module doc); ``straight``: no steering at all."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    t = np.arange(0.0, duration_s, dt)
    v = (
        speed_mps
        + speed_swing_mps * np.sin(2 * np.pi * t / 17.0)
        + 0.5 * speed_swing_mps * np.sin(2 * np.pi * t / 6.3 + 1.0)
        + speed_ripple_mps * np.sin(2 * np.pi * 0.8 * t)
    )  # surging at 0.8 Hz
    sw = (
        np.zeros_like(t)
        if straight
        else sw_amp_rad
        * (np.sin(2 * np.pi * t / sw_period_s) + 0.3 * np.sin(2 * np.pi * t / (0.37 * sw_period_s)))
    )
    k = int(round(steer_delay_s / dt))
    sw_eff = np.concatenate([np.full(k, sw[0]), sw[: len(sw) - k]]) if k else sw
    delta = SCALE * sw_eff
    r = v * np.tan(delta) / WHEELBASE_M
    psi = np.cumsum(r) * dt
    x, y = np.cumsum(v * np.cos(psi)) * dt, np.cumsum(v * np.sin(psi)) * dt
    a = np.gradient(v, dt)
    q = v * r
    half = 0.5 * TRACK_M * track_scale
    rl, rr = v - r * half, (v + r * half) * (1.0 + side_ratio)
    fl, fr = (v - r * half) / np.cos(delta), (v + r * half) / np.cos(delta) * (1.0 + side_ratio)
    ch = {"time": t, "steering_wheel_angle": sw + 0.001 * rng.standard_normal(len(t))}
    for name, w in (
        ("wheel_speed_fl", fl),
        ("wheel_speed_fr", fr),
        ("wheel_speed_rl", rl),
        ("wheel_speed_rr", rr),
    ):
        ch[name] = np.round((w + 0.003 * rng.standard_normal(len(t))) / KMH_STEP) * KMH_STEP
    ch["speed"] = 0.25 * (
        ch["wheel_speed_fl"] + ch["wheel_speed_fr"] + ch["wheel_speed_rl"] + ch["wheel_speed_rr"]
    )
    ch["yaw_rate"] = r + 0.002 * rng.standard_normal(len(t))
    ax_body, ay_body = a, q
    if accel_tau_s > 0:
        al = 1.0 - np.exp(-dt / accel_tau_s)
        ax_body = lfilter([al], [1.0, al - 1.0], a, zi=[(1.0 - al) * a[0]])[0]
        ay_body = lfilter([al], [1.0, al - 1.0], q, zi=[(1.0 - al) * q[0]])[0]
    if accel_smooth_s > 0:  # the same lag forwards and backwards: smoother, not later
        al = 1.0 - np.exp(-dt / accel_smooth_s)
        for _ in range(2):
            ax_body = lfilter([al], [1.0, al - 1.0], ax_body, zi=[(1.0 - al) * ax_body[0]])[0]
            ax_body = ax_body[::-1]
    c, s = np.cos(imu_yaw_rad), np.sin(imu_yaw_rad)  # imu = R(-yaw) body
    ch["accel_x"] = c * ax_body + s * ay_body + 0.05 * rng.standard_normal(len(t))
    ch["accel_y"] = -s * ax_body + c * ay_body + 0.05 * rng.standard_normal(len(t))
    if pedals:
        ch["accel_pedal"] = np.clip(0.15 + 0.1 * a, 0.0, 1.0)
        ch["brake_pedal"] = np.zeros_like(t)
    if ins:
        ch["x"], ch["y"], ch["heading"] = x, y, np.angle(np.exp(1j * psi))
        ch["gps_speed"] = v + 0.02 * rng.standard_normal(len(t))
    return Recording(ch, meta={"path": path})
