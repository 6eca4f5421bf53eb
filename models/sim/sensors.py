"""Sensor models of the ground-truth simulator: a 2017 RAV4's CAN signals and a survey-grade INS.

Pure functions of the simulator's truth (``models.sim``); nothing here integrates dynamics.

Geometry (ISO 8855 body axes, x forward, y left; the report's eq. 1 point is the front-axle
centre F, moving at speed v in the direction heading + delta; yaw rate r = v sin(delta) / b):

- front wheels at F +- (0, T_f/2): body velocity (v cos delta -+ r T_f/2, v sin delta), so
  ``fr^2 - fl^2 = 2 r T_f v cos(delta)``: the report's eq. 5, ``r = (fr - fl) / T_f``, holds to a
  factor ``cos(delta) * v / mean(fl, fr)`` (within 1 % for |delta| < 0.14 rad, 5 % at 0.31 rad);
- rear axle centre moves at v cos(delta) straight ahead (no side slip), rear wheels at
  ``v cos(delta) -+ r T_r/2``: ``rr - rl = r T_r`` exactly, and
  ``tan(delta) = b (rr - rl) / (T_r (rr + rl) / 2)`` exactly (:func:`road_wheel_angle_from_rear`).

CAN signals (the RAV4 powertrain DBC ``toyota_rav4_2017.dbc``; rates measured on the comma2k19
minute): each message is sent periodically with its own random phase and a small timing jitter,
its signals are quantised as the DBC encodes them, and the recording holds the last message at
or before each grid time (zero-order hold, as ingest's ``hold``):

=====================  =========================  ==========  ===============================
channel                DBC message.signal          rate [Hz]   step (DBC factor)
=====================  =========================  ==========  ===============================
steering_wheel_angle   STEER_ANGLE_SENSOR           83.3        1.5 deg + 0.1 deg fraction
                       .STEER_ANGLE+STEER_FRACTION              = 0.1 deg
wheel_speed_*          WHEEL_SPEEDS.WHEEL_SPEED_*   83.3        0.01 km/h (offset -67.67)
speed                  mean of the WHEEL_SPEEDS     83.3        mean of four 0.01 km/h values
accel_pedal            GAS_PEDAL.GAS_PEDAL          31.5        0.5 %
brake_pedal            BRAKE_MODULE (see below)     41.5        0.5 %
engine_rpm             ENGINE_RPM.RPM               42.5        0.78125 rpm
gear                   GEAR_PACKET.GEAR              1.1        -
=====================  =========================  ==========  ===============================

``speed`` is the mean of the four wheel speeds, the channel the RAV4 signal map names (see
``params/toyota_rav4_2017.signals.yaml``), not the speedometer message. This DBC gives no
calibrated brake pedal travel, so ``brake_pedal`` is a normalised brake demand with the gas
pedal's 0.5 % step, sent at the BRAKE_MODULE rate.

INS (a NovAtel SPAN-class GNSS/INS as in the report, reference point = the front-axle centre F,
the eq. 1 point, i.e. lever arm already applied), sampled at the simulator's internal rate
(100 Hz by default); noise numbers of ``InsNoise``:

- ``x``, ``y``: first-order Gauss-Markov errors, 0.02 m rms, correlation time 1 s (RTK class);
  ``z``: 0.03 m rms, 2 s;
- ``heading``: Gauss-Markov 0.1 deg rms, 5 s; ``pitch``, ``roll``: 0.05 deg rms, 5 s;
- ``yaw_rate``: white 0.005 rad/s rms plus a constant bias drawn uniformly in +-0.002 rad/s;
- ``accel_x``, ``accel_y``: body-frame kinematic acceleration of F (gravity removed), white
  0.05 m/s^2 rms plus a constant bias drawn from N(0, 0.01 m/s^2) clipped to +-0.02 m/s^2;
- ``gps_speed``: horizontal speed of F, white 0.02 m/s rms (reported as a magnitude).

Body-frame acceleration of F (v along delta, body turning at r):
``accel_x = a cos(delta) - v sin(delta) (r + d delta/dt)``,
``accel_y = a sin(delta) + v cos(delta) (r + d delta/dt)``; on a straight road accel_x = dv/dt.
Body attitude: pitch = grade + 0.002 rad per m/s^2 of accel_x (squat, nose up under throttle),
roll = 0.006 rad per m/s^2 of accel_y (about 3.4 deg/g, SUV-like body roll).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

KPH_PER_MPS = 3.6


@dataclass(frozen=True)
class Drivetrain:
    """Engine and gearbox of :func:`engine_rpm`. ``params.Vehicle`` has no drivetrain fields, so
    these are the 2017 RAV4's, the car the sensor models copy; the tyre radius comes from the
    Vehicle (:func:`wheel_radius_m`)."""

    #: warm idle speed [1/min] (the 2.5 l 2AR-FE idles at about 700 rpm).
    idle_rpm: float = 700.0
    #: 6-speed automatic (U760E) gear ratios and final drive.
    gear_ratios: tuple[float, ...] = (3.300, 1.900, 1.420, 1.000, 0.713, 0.608)
    final_drive: float = 3.815
    #: upshift speeds [m/s] at light throttle (1-2, 2-3, 3-4, 4-5, 5-6); a full pedal delays
    #: them x1.6.
    upshift_mps: tuple[float, ...] = (4.0, 7.0, 10.0, 14.0, 18.0)


RAV4_DRIVETRAIN = Drivetrain()
#: tyre rolling radius [m] used only when the Vehicle gives no ``wheel_radius_m`` (the RAV4's
#: 225/65 R17: 17 in / 2 + 0.65 x 225 mm, unloaded; ``params/toyota_rav4_2017.yaml`` has it).
DEFAULT_WHEEL_RADIUS_M = 0.362


def wheel_radius_m(vehicle) -> float:
    """The Vehicle's ``wheel_radius_m`` [m], or :data:`DEFAULT_WHEEL_RADIUS_M` when it has none."""
    r = getattr(vehicle, "wheel_radius_m", None)
    return DEFAULT_WHEEL_RADIUS_M if r is None else float(r)


@dataclass(frozen=True)
class CanSignal:
    """One CAN-borne channel: its DBC source, message rate and quantisation.

    Attributes:
        channel: canonical channel name.
        message: DBC message name; signal: DBC signal name(s).
        rate_hz: message rate measured on the comma2k19 RAV4 minute [Hz].
        step_si: quantisation step in the channel's SI unit (see ``step_dbc``/``unit_dbc``).
        step_dbc: the DBC factor [unit_dbc]; offset_dbc: the DBC offset [unit_dbc].
    """

    channel: str
    message: str
    signal: str
    rate_hz: float
    step_dbc: float
    unit_dbc: str
    offset_dbc: float = 0.0
    noise_dbc: float = 0.0  #: white noise added before quantisation at noise="typical" [unit_dbc]

    @property
    def to_si(self) -> float:
        return {"deg": np.pi / 180.0, "km/h": 1.0 / KPH_PER_MPS, "%": 0.01, "rpm": 1.0, "": 1.0}[
            self.unit_dbc
        ]

    @property
    def step_si(self) -> float:
        return self.step_dbc * self.to_si


#: the CAN channels, in the order of ``models.logs.channels.CHANNELS``. Noise: wheel speeds
#: jitter by 0.02 km/h rms (tone-wheel edge timing), rpm by 5 rpm; angle and pedal sensors are exact
#: encoders. Rates: comma2k19 minute (82.9, 31.5, 41.5, 42.5, 1.1 Hz).
CAN_SIGNALS: tuple[CanSignal, ...] = (
    CanSignal(
        "steering_wheel_angle", "STEER_ANGLE_SENSOR", "STEER_ANGLE+STEER_FRACTION", 83.3, 0.1, "deg"
    ),
    CanSignal("wheel_speed_fl", "WHEEL_SPEEDS", "WHEEL_SPEED_FL", 83.3, 0.01, "km/h", -67.67, 0.02),
    CanSignal("wheel_speed_fr", "WHEEL_SPEEDS", "WHEEL_SPEED_FR", 83.3, 0.01, "km/h", -67.67, 0.02),
    CanSignal("wheel_speed_rl", "WHEEL_SPEEDS", "WHEEL_SPEED_RL", 83.3, 0.01, "km/h", -67.67, 0.02),
    CanSignal("wheel_speed_rr", "WHEEL_SPEEDS", "WHEEL_SPEED_RR", 83.3, 0.01, "km/h", -67.67, 0.02),
    CanSignal("accel_pedal", "GAS_PEDAL", "GAS_PEDAL", 31.5, 0.5, "%"),
    CanSignal("brake_pedal", "BRAKE_MODULE", "(normalised brake demand)", 41.5, 0.5, "%"),
    CanSignal("engine_rpm", "ENGINE_RPM", "RPM", 42.5, 0.78125, "rpm", 0.0, 5.0),
)
#: message timing jitter [s] rms at noise="typical" (bus arbitration; well below a period).
CAN_JITTER_S = 0.0002
GEAR_RATE_HZ = 1.1


@dataclass(frozen=True)
class InsNoise:
    """INS error model (see the module docstring for the reasons); all 1-sigma."""

    pos_xy_m: float = 0.02
    pos_xy_tau_s: float = 1.0
    pos_z_m: float = 0.03
    pos_z_tau_s: float = 2.0
    heading_rad: float = np.deg2rad(0.1)
    heading_tau_s: float = 5.0
    attitude_rad: float = np.deg2rad(0.05)
    attitude_tau_s: float = 5.0
    yaw_rate_radps: float = 0.005
    yaw_rate_bias_max_radps: float = 0.002
    accel_mps2: float = 0.05
    accel_bias_mps2: float = 0.01
    accel_bias_max_mps2: float = 0.02
    gps_speed_mps: float = 0.02


#: body attitude response (see module docstring) [rad per m/s^2]
PITCH_PER_ACCEL = 0.002
ROLL_PER_LATERAL_ACCEL = 0.006


# --------------------------------------------------------------------------- geometry
def wheel_speeds(
    v_mps, delta_rad, wheelbase_m: float, track_front_m: float, track_rear_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Wheel-centre speeds (fl, fr, rl, rr) [m/s] of the kinematic bicycle (module docstring).

    Args:
        v_mps: speed of the front-axle centre (eq. 1's v) [m/s].
        delta_rad: road-wheel angle of the virtual middle tyre [rad].
        wheelbase_m: wheelbase [m].
        track_front_m: front track width [m].
        track_rear_m: rear track width [m].
    """
    v = np.asarray(v_mps, dtype=float)
    d = np.asarray(delta_rad, dtype=float)
    r = v * np.sin(d) / wheelbase_m
    vx, vy = v * np.cos(d), v * np.sin(d)
    half_f, half_r = 0.5 * track_front_m * r, 0.5 * track_rear_m * r
    fl = np.hypot(vx - half_f, vy)
    fr = np.hypot(vx + half_f, vy)
    rl = np.abs(vx - half_r)
    rr = np.abs(vx + half_r)
    return fl, fr, rl, rr


def road_wheel_angle_from_rear(rl_mps, rr_mps, wheelbase_m: float, track_rear_m: float):
    """Exact inverse of :func:`wheel_speeds` from the rear wheels: delta [rad] (NaN at rest)."""
    rl = np.asarray(rl_mps, dtype=float)
    rr = np.asarray(rr_mps, dtype=float)
    mean = 0.5 * (rl + rr)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.arctan(wheelbase_m * (rr - rl) / (track_rear_m * mean))
    return np.where(mean > 0, out, np.nan)


def ins_body_accel(v_mps, a_mps2, delta_rad, delta_rate_radps, wheelbase_m: float):
    """Body-frame acceleration (accel_x, accel_y) [m/s^2] of the front-axle centre (docstring)."""
    v = np.asarray(v_mps, dtype=float)
    d = np.asarray(delta_rad, dtype=float)
    turn = v * np.sin(d) / wheelbase_m + np.asarray(delta_rate_radps, dtype=float)
    return (
        np.asarray(a_mps2) * np.cos(d) - v * np.sin(d) * turn,
        np.asarray(a_mps2) * np.sin(d) + v * np.cos(d) * turn,
    )


def engine_rpm(
    v_mps, accel_pedal, vehicle, low_gear_only=None, *, drivetrain: Drivetrain = RAV4_DRIVETRAIN
) -> np.ndarray:
    """A plausible engine speed [1/min]: idle plus throttle flare, or wheel speed through the gear.

    Args:
        v_mps: speed [m/s].
        accel_pedal: accelerator pedal [0..1].
        vehicle: ``params.Vehicle`` (its ``wheel_radius_m``, see :func:`wheel_radius_m`).
        low_gear_only: bool array restricting to gears 1-2 (the report's "Low" gear).
        drivetrain: engine and gearbox (the RAV4's by default, see :class:`Drivetrain`).

    Gear chosen by speed from ``drivetrain.upshift_mps`` (later under throttle). Torque-converter
    slip adds up to 10 % under full throttle. Not part of any identified model: it makes the
    recording complete.
    """
    v = np.maximum(np.asarray(v_mps, dtype=float), 0.0)
    p = np.clip(np.asarray(accel_pedal, dtype=float), 0.0, 1.0)
    shift = np.asarray(drivetrain.upshift_mps)[None, :] * (1.0 + 0.6 * p[:, None])
    gear = np.sum(v[:, None] > shift, axis=1)  # 0-based
    if low_gear_only is not None:
        gear = np.where(np.asarray(low_gear_only, dtype=bool), np.minimum(gear, 1), gear)
    ratio = np.asarray(drivetrain.gear_ratios)[gear] * drivetrain.final_drive
    geared = v / wheel_radius_m(vehicle) * ratio * 60.0 / (2.0 * np.pi) * (1.0 + 0.1 * p)
    return np.maximum(drivetrain.idle_rpm + 1500.0 * p * np.clip(1.0 - v / 3.0, 0.0, 1.0), geared)


# ------------------------------------------------------------------------- quantisation
def quantise_dbc(value_si, sig: CanSignal) -> np.ndarray:
    """Encode ``value_si`` as the DBC would (nearest raw count) and decode back to SI."""
    x = np.asarray(value_si, dtype=float) / sig.to_si
    if sig.channel == "steering_wheel_angle":
        return steer_angle_sensor_deg(x) * sig.to_si
    raw = np.round((x - sig.offset_dbc) / sig.step_dbc)
    raw = np.maximum(raw, 0.0) if sig.offset_dbc == 0.0 else raw
    return (raw * sig.step_dbc + sig.offset_dbc) * sig.to_si


def steer_angle_sensor_deg(angle_deg) -> np.ndarray:
    """The RAV4 steering-angle sensor: STEER_ANGLE (1.5 deg) + STEER_FRACTION (0.1 deg, +-0.7).

    Returns the decoded angle [deg] (the sum the signal map forms), a 0.1 deg grid.
    """
    a = np.asarray(angle_deg, dtype=float)
    coarse = 1.5 * np.round(a / 1.5)
    frac = np.clip(np.round((a - coarse) / 0.1), -7, 7) * 0.1
    return np.round((coarse + frac) * 10.0) / 10.0  # drop float dust: exact 0.1 deg grid


# ------------------------------------------------------------------------------ noise
def gauss_markov(
    rng: np.random.Generator, n: int, sigma: float, tau_s: float, dt_s: float
) -> np.ndarray:
    """A stationary first-order Gauss-Markov sequence: rms ``sigma``, correlation time ``tau_s``."""
    if n == 0 or sigma == 0.0:
        return np.zeros(n)
    phi = float(np.exp(-dt_s / tau_s))
    w = rng.standard_normal(n)
    x0 = sigma * w[0]
    rest = lfilter([sigma * np.sqrt(1.0 - phi * phi)], [1.0, -phi], w[1:], zi=[phi * x0])[0]
    return np.concatenate([[x0], rest])


# --------------------------------------------------------------------------- sampling
def message_times(
    rng: np.random.Generator | None,
    rate_hz: float,
    t_start_s: float,
    t_end_s: float,
    jitter_s: float,
) -> np.ndarray:
    """Send times [s] of a periodic message covering [t_start, t_end], random phase and jitter.

    ``rng`` None: phase 0 and no jitter. Strictly increasing.
    """
    period = 1.0 / rate_hz
    phase = 0.0 if rng is None else float(rng.uniform(0.0, period))
    count = int(np.ceil((t_end_s - t_start_s) / period)) + 2
    t = t_start_s - period + phase + period * np.arange(count)
    if rng is not None and jitter_s > 0:
        t = t + np.clip(rng.normal(0.0, jitter_s, t.shape), -0.25 * period, 0.25 * period)
    return t


def hold_on_grid(t_rec_s: np.ndarray, values: np.ndarray, grid_s: np.ndarray) -> np.ndarray:
    """Zero-order hold: the last value stamped at or before each grid time (NaN/"" before any)."""
    idx = np.searchsorted(t_rec_s, grid_s, side="right") - 1
    out = values[np.maximum(idx, 0)]
    if np.any(idx < 0):
        out = out.copy()
        out[idx < 0] = "" if out.dtype == object else np.nan
    return out
