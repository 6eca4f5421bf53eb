"""Sensors as a car has them, for closed-loop simulation: timestamped measurement events.

:class:`LiveSensors` is fed the true state sample by sample (as a closed loop steps its plant)
and returns the measurements that have *arrived* by then, each stamped with the time it was
taken (``t_meas_s``) and the time it reaches the controller (``t_arrival_s``). Three streams,
each with its own rate, random phase (seeded) and latency:

- ``can``: the RAV4's ``WHEEL_SPEEDS`` and ``STEER_ANGLE_SENSOR`` (both 83.3 Hz on the comma2k19
  minute, see ``models.sim.sensors.CAN_SIGNALS``): the four wheel speeds of the kinematic
  bicycle (``sensors.wheel_speeds``), quantised to the DBC's 0.01 km/h, and the steering-wheel
  angle quantised as the angle sensor encodes it (0.1 deg). Optionally (``can_yaw_rate``) the
  ``KINEMATICS`` yaw rate, with its own bias.
- ``imu``: yaw rate (gyro, white noise plus a constant bias) and longitudinal acceleration,
  100 Hz.
- ``gnss``: GNSS/INS position of the eq. 1 point, heading and horizontal speed, at
  ``gnss_rate_hz`` with ``gnss_latency_s``; outage windows give no fix; optional jumps add an
  offset to the position (outliers, e.g. a multipath or a wrong RTK fix).

Noise defaults are the closed loop's (``controller.closed_loop``: 2 cm white position
noise, 0.05 m/s speed noise): the 0.05 m/s is added to all four wheel speeds alike (a speed
error, as the closed loop adds it to the measured speed) and to the GNSS speed; each wheel also
has its own 0.02 km/h edge-timing jitter (``sensors.CAN_SIGNALS``). ``noise_scale`` multiplies
every random error (3 for the robustness runs); quantisation is not scaled.

The measurement instant of a message generally falls between two truth samples: the truth is
interpolated linearly (heading on the circle) between the previous and the current sample.
Runs are repeatable: ``SeedSequence(seed)`` feeds separate streams for phases, CAN, IMU and GNSS.

Also here: :func:`measure_trajectory` (every message of a whole true trajectory) and
:func:`random_drive` (a seeded open-loop drive of the hybrid plant with optional hidden process
noise: known truth for the estimator's tests and benchmark).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant, heading_rate
from hmpc.models.sim import sensors as sn

KINDS = ("can", "imu", "gnss")
_WHEEL_SIGNAL = next(q for q in sn.CAN_SIGNALS if q.channel == "wheel_speed_fl")


@dataclass(frozen=True)
class SensorConfig:
    """Rates [Hz], latencies [s] and noise (1-sigma) of the simulated sensors."""

    #: WHEEL_SPEEDS and STEER_ANGLE_SENSOR rate on the comma2k19 RAV4 minute (82.9 Hz).
    can_rate_hz: float = 83.3
    #: CAN transport delay: one 500 kbit/s frame plus gateway, well under a millisecond.
    can_latency_s: float = 0.0
    #: speed error common to the four wheels: the closed loop's default (--speed-noise 0.05).
    speed_noise_mps: float = 0.05
    #: per-wheel edge-timing jitter: 0.02 km/h (models.sim.sensors CAN_SIGNALS noise_dbc).
    wheel_jitter_mps: float = 0.02 / 3.6
    #: tyre rolling radius error as a wheel-speed scale (1 = exact; 1.02 = tyres 2 % large).
    wheel_speed_scale: float = 1.0
    #: send the KINEMATICS yaw rate on CAN as well (the RAV4 has it; off: the IMU's is used).
    can_yaw_rate: bool = False
    #: KINEMATICS yaw rate noise and bias bound [rad/s] (same class as the INS gyro).
    can_yaw_rate_noise_radps: float = 0.005
    can_yaw_rate_bias_max_radps: float = 0.002
    #: IMU rate: the comma2k19 minute's phone IMU runs at about 104 Hz.
    imu_rate_hz: float = 100.0
    imu_latency_s: float = 0.0
    #: gyro white noise and constant bias bound [rad/s] (models.sim.sensors.InsNoise).
    gyro_noise_radps: float = 0.005
    gyro_bias_max_radps: float = 0.002
    #: accelerometer white noise and bias [m/s^2] (InsNoise).
    accel_noise_mps2: float = 0.05
    accel_bias_mps2: float = 0.01
    #: GNSS/INS fixes: comma's INS solution comes at 20 Hz; a receiver's fix takes tens of ms.
    gnss_rate_hz: float = 20.0
    gnss_latency_s: float = 0.05
    #: GNSS position noise [m], white: the closed loop's default (2 cm, RTK class).
    position_noise_m: float = 0.02
    #: GNSS/INS heading noise [rad]: 0.1 deg (InsNoise, dual-antenna/INS class).
    heading_noise_rad: float = math.radians(0.1)
    #: GNSS speed noise [m/s]: the closed loop's default speed noise.
    gnss_speed_noise_mps: float = 0.05
    #: GNSS outage windows (t_start_s, t_end_s): no fix is taken inside.
    gnss_outages: tuple[tuple[float, float], ...] = ()
    #: GNSS position jumps (t_start_s, t_end_s, dx_m, dy_m): fixes inside are offset (outliers).
    gnss_jumps: tuple[tuple[float, float, float, float], ...] = ()
    #: multiplies every random error (not quantisation).
    noise_scale: float = 1.0

    def __post_init__(self):
        for name in ("can_rate_hz", "imu_rate_hz", "gnss_rate_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        for name in ("can_latency_s", "imu_latency_s", "gnss_latency_s", "noise_scale"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be >= 0, got {v!r}")
        for w in self.gnss_outages:
            if len(w) != 2 or not w[0] < w[1]:
                raise ValueError(f"gnss_outages entries are (t_start_s, t_end_s), got {w!r}")
        for j in self.gnss_jumps:
            if len(j) != 4 or not j[0] < j[1]:
                raise ValueError(
                    f"gnss_jumps entries are (t_start_s, t_end_s, dx_m, dy_m), got {j!r}"
                )


@dataclass(slots=True)
class Measurement:
    """One message: which stream, when it was measured and when it arrives, and its values.

    ``values`` keys (SI): can: ``wheel_speeds_mps`` (fl, fr, rl, rr), ``steering_wheel_angle_rad``
    and, with ``can_yaw_rate``, ``yaw_rate_radps``; imu: ``yaw_rate_radps``, ``accel_x_mps2``;
    gnss: ``x_m``, ``y_m``, ``heading_rad``, ``speed_mps``.
    """

    kind: str
    t_meas_s: float
    t_arrival_s: float
    values: dict = field(default_factory=dict)


@dataclass
class _Stream:
    period_s: float
    latency_s: float
    next_t_s: float


class LiveSensors:
    """Simulated car sensors fed the truth one sample at a time (see the module docstring).

    Args:
        params: the plant's parameters (geometry, steering map eq. 7 for the road-wheel angle).
        config: rates, latencies, noise.
        seed: seeds phases, noise and biases (``sensor_truth`` holds the biases drawn).
        t0_s: time of the first truth sample [s]; each stream's first message is within one
            period after it.
    """

    def __init__(
        self, params: Params, config: SensorConfig | None = None, seed: int = 0, t0_s: float = 0.0
    ):
        if params.steering is None:
            raise ValueError("LiveSensors needs a parameter file with the steering map (eq. 7)")
        self.params = params
        self.cfg = cfg = config or SensorConfig()
        self.seed = int(seed)
        veh = params.vehicle
        self._b = float(veh.wheelbase_m)
        self._tf = float(veh.track_front_m)
        self._tr = float(veh.track_rear_m if veh.track_rear_m is not None else veh.track_front_m)
        self._off = float(params.steering.offset_rad)
        self._scale = float(params.steering.scale)
        ss = np.random.SeedSequence(self.seed)
        rng_phase, self._rng_can, self._rng_imu, self._rng_gnss = (
            np.random.default_rng(s) for s in ss.spawn(4)
        )
        k = cfg.noise_scale
        self.sensor_truth = {
            "gyro_bias_radps": k
            * float(rng_phase.uniform(-cfg.gyro_bias_max_radps, cfg.gyro_bias_max_radps)),
            "can_yaw_rate_bias_radps": k
            * float(
                rng_phase.uniform(-cfg.can_yaw_rate_bias_max_radps, cfg.can_yaw_rate_bias_max_radps)
            ),
            "accel_x_bias_mps2": k * float(rng_phase.normal(0.0, cfg.accel_bias_mps2)),
            "wheel_speed_scale": cfg.wheel_speed_scale,
        }
        self._streams = {}
        for kind, rate, lat in (
            ("can", cfg.can_rate_hz, cfg.can_latency_s),
            ("imu", cfg.imu_rate_hz, cfg.imu_latency_s),
            ("gnss", cfg.gnss_rate_hz, cfg.gnss_latency_s),
        ):
            period = 1.0 / rate
            self._streams[kind] = _Stream(period, lat, t0_s + float(rng_phase.uniform(0, period)))
        self._prev: tuple | None = None
        self._queue: list[Measurement] = []
        self.counts = {"can": 0, "imu": 0, "gnss": 0, "gnss_outage": 0, "gnss_jump": 0}

    # ------------------------------------------------------------------ truth
    def _truth_at(self, t_s: float, prev: tuple, cur: tuple) -> tuple:
        t0, s0, sw0, d0, a0 = prev
        t1, s1, sw1, d1, a1 = cur
        w = 0.0 if t1 <= t0 else min(max((t_s - t0) / (t1 - t0), 0.0), 1.0)
        dpsi = math.remainder(s1[2] - s0[2], 2 * math.pi)
        s = (
            s0[0] + w * (s1[0] - s0[0]),
            s0[1] + w * (s1[1] - s0[1]),
            s0[2] + w * dpsi,
            s0[3] + w * (s1[3] - s0[3]),
        )
        return s, sw0 + w * (sw1 - sw0), d0 + w * (d1 - d0), a0 + w * (a1 - a0)

    def observe(
        self,
        t_s: float,
        state,
        steering_wheel_angle_rad: float,
        accel_mps2: float = 0.0,
        delta_rad: float | None = None,
    ) -> list[Measurement]:
        """Feed the truth at ``t_s``; return the messages that arrive in (previous t, t_s].

        Args:
            t_s: truth time [s], increasing from call to call.
            state: true plant state (x_m, y_m, psi_rad, v_mps) at ``t_s`` (eq. 1 point).
            steering_wheel_angle_rad: the steering-wheel angle the car has at ``t_s`` (what the
                angle sensor reads) [rad].
            accel_mps2: true longitudinal acceleration [m/s^2] (what the IMU reads, before noise).
            delta_rad: true road-wheel angle [rad]; default eq. 7 of the steering-wheel angle
                (pass it when the truth's steering map differs from ``params``).

        Returns:
            arrived messages in order of arrival (then of measurement time).
        """
        d = self._off + self._scale * steering_wheel_angle_rad if delta_rad is None else delta_rad
        cur = (
            float(t_s),
            tuple(float(q) for q in state[:4]),
            float(steering_wheel_angle_rad),
            float(d),
            float(accel_mps2),
        )
        prev = self._prev if self._prev is not None else cur
        if self._prev is not None and cur[0] <= prev[0]:
            raise ValueError(f"truth times must increase: {cur[0]} after {prev[0]}")
        for kind, st in self._streams.items():
            while st.next_t_s <= t_s:
                tm = st.next_t_s
                st.next_t_s += st.period_s
                if tm < prev[0] and self._prev is not None:
                    continue
                m = self._measure(kind, tm, *self._truth_at(tm, prev, cur))
                if m is not None:
                    m.t_arrival_s = tm + st.latency_s
                    self._queue.append(m)
        self._prev = cur
        out = [m for m in self._queue if m.t_arrival_s <= t_s + 1e-12]
        if out:
            self._queue = [m for m in self._queue if m.t_arrival_s > t_s + 1e-12]
            out.sort(key=lambda m: (m.t_arrival_s, m.t_meas_s))
        return out

    # ---------------------------------------------------------------- sensors
    def _measure(
        self, kind: str, t: float, s, sw: float, delta: float, a: float
    ) -> Measurement | None:
        cfg, k = self.cfg, self.cfg.noise_scale
        v = max(s[3], 0.0)
        r = heading_rate(v, delta, self._b, math)
        if kind == "can":
            rng = self._rng_can
            fl, fr, rl, rr = sn.wheel_speeds(v, delta, self._b, self._tf, self._tr)
            common = k * cfg.speed_noise_mps * rng.standard_normal()
            ws = (
                np.array([fl, fr, rl, rr]) * cfg.wheel_speed_scale
                + common
                + k * cfg.wheel_jitter_mps * rng.standard_normal(4)
            )
            ws = _quantise_wheel_speed(np.maximum(ws, 0.0))
            vals = {
                "wheel_speeds_mps": tuple(float(q) for q in ws),
                "steering_wheel_angle_rad": float(
                    np.deg2rad(sn.steer_angle_sensor_deg(np.rad2deg(sw)))
                ),
            }
            if cfg.can_yaw_rate:
                vals["yaw_rate_radps"] = (
                    r
                    + self.sensor_truth["can_yaw_rate_bias_radps"]
                    + k * cfg.can_yaw_rate_noise_radps * rng.standard_normal()
                )
            self.counts["can"] += 1
            return Measurement("can", t, t, vals)
        if kind == "imu":
            rng = self._rng_imu
            self.counts["imu"] += 1
            return Measurement(
                "imu",
                t,
                t,
                {
                    "yaw_rate_radps": r
                    + self.sensor_truth["gyro_bias_radps"]
                    + k * cfg.gyro_noise_radps * rng.standard_normal(),
                    "accel_x_mps2": a
                    + self.sensor_truth["accel_x_bias_mps2"]
                    + k * cfg.accel_noise_mps2 * rng.standard_normal(),
                },
            )
        # gnss: draw the noise even inside an outage, so outages do not shift the other fixes
        rng = self._rng_gnss
        e = rng.standard_normal(4)
        if any(a0 <= t < a1 for a0, a1 in cfg.gnss_outages):
            self.counts["gnss_outage"] += 1
            return None
        dx = dy = 0.0
        for j0, j1, jx, jy in cfg.gnss_jumps:
            if j0 <= t < j1:
                dx, dy = dx + jx, dy + jy
                self.counts["gnss_jump"] += 1
        self.counts["gnss"] += 1
        return Measurement(
            "gnss",
            t,
            t,
            {
                "x_m": s[0] + dx + k * cfg.position_noise_m * e[0],
                "y_m": s[1] + dy + k * cfg.position_noise_m * e[1],
                "heading_rad": math.remainder(s[2] + k * cfg.heading_noise_rad * e[2], 2 * math.pi),
                "speed_mps": abs(v + k * cfg.gnss_speed_noise_mps * e[3]),
            },
        )

    def pending(self) -> int:
        """Messages measured but not yet arrived (latency in flight)."""
        return len(self._queue)


def _quantise_wheel_speed(ws_mps: np.ndarray) -> np.ndarray:
    """WHEEL_SPEEDS encoding: 0.01 km/h steps, offset -67.67 km/h (the DBC's)."""
    return sn.quantise_dbc(ws_mps, _WHEEL_SIGNAL)


def measure_trajectory(
    params: Params,
    t_s,
    states,
    steering_wheel_angle_rad,
    accel_mps2=None,
    delta_rad=None,
    config: SensorConfig | None = None,
    seed: int = 0,
) -> list[Measurement]:
    """Every message of a whole true trajectory, in order of arrival.

    Args:
        params: the car (geometry and steering map).
        t_s: truth times [s] (n,).
        states: (n, 4) plant states.
        steering_wheel_angle_rad: (n,) steering-wheel angle [rad].
        accel_mps2: (n,) true longitudinal acceleration [m/s^2] (default zeros).
        delta_rad: (n,) true road-wheel angle [rad] (default eq. 7).
        config: sensor rates, latencies and noise (default ``SensorConfig()``).
        seed: seed of the noise streams.
    """
    t = np.asarray(t_s, dtype=float)
    s = np.asarray(states, dtype=float)
    sw = np.asarray(steering_wheel_angle_rad, dtype=float)
    a = np.zeros(len(t)) if accel_mps2 is None else np.asarray(accel_mps2, dtype=float)
    sensors = LiveSensors(params, config, seed, t0_s=float(t[0]))
    out: list[Measurement] = []
    for i in range(len(t)):
        out.extend(
            sensors.observe(
                t[i], s[i], sw[i], a[i], None if delta_rad is None else float(delta_rad[i])
            )
        )
    return out


# --------------------------------------------------------------- known-truth drives
@dataclass
class TruthTrajectory:
    """A true drive on a uniform grid (row i at ``t_s[i]``; inputs held over the step after it).

    Attributes:
        t_s: (n,) [s]; states: (n, 4) plant state at ``t_s``; steering_wheel_angle_rad: (n,)
        what the angle sensor reads; delta_rad: (n,) true road-wheel angle; accel_mps2: (n,)
        acceleration applied over the step; u: (n, 3) plant input (sw, accel pedal, brake).
    """

    t_s: np.ndarray
    states: np.ndarray
    steering_wheel_angle_rad: np.ndarray
    delta_rad: np.ndarray
    accel_mps2: np.ndarray
    u: np.ndarray


def _ou(rng: np.random.Generator, n: int, sigma: float, tau_s: float, dt_s: float) -> np.ndarray:
    return sn.gauss_markov(rng, n, sigma, tau_s, dt_s)


def random_drive(
    params: Params,
    duration_s: float,
    seed: int,
    *,
    dt_s: float = 0.01,
    v0_mps: float = 6.0,
    v_range_mps: tuple[float, float] = (2.0, 12.0),
    steer_rms_rad: float = 0.08,
    speed_walk_mps_rts: float = 0.0,
    heading_walk_rad_rts: float = 0.0,
    position_walk_m_rts: float = 0.0,
    delta_offset_walk_rad_rts: float = 0.0,
) -> TruthTrajectory:
    """A seeded open-loop drive of ``models.plant.HybridPlant`` with smooth random inputs.

    Steering: a Gauss-Markov road-wheel angle (``steer_rms_rad`` rms, 2 s correlation, through
    a 0.3 s lag) mapped to
    the steering wheel by eq. 7. Pedals: eq. 8 inverted for a random desired acceleration
    (0.5 m/s^2 rms, 3 s) pulled back into ``v_range_mps`` (throttle or brake, never both).
    The ``*_walk_*`` densities add hidden process noise to the truth (white acceleration,
    heading and position random walks, a drifting road-wheel angle offset that the steering
    sensor does not see): with the estimator's own densities they make the truth follow the
    estimator's process model, which a consistency (NEES) test needs.
    """
    plant = HybridPlant(params)
    n = int(round(duration_s / dt_s)) + 1
    ss = np.random.SeedSequence(int(seed))
    rng_in, rng_w = (np.random.default_rng(s) for s in ss.spawn(2))
    # a Gauss-Markov road-wheel angle through a 0.3 s lag: a hand on a wheel is smooth
    delta_cmd = lfilter(
        [1.0 - math.exp(-dt_s / 0.3)],
        [1.0, -math.exp(-dt_s / 0.3)],
        _ou(rng_in, n, steer_rms_rad, 2.0, dt_s),
    )
    a_des = _ou(rng_in, n, 0.5, 3.0, dt_s)
    psi0 = float(rng_in.uniform(-math.pi, math.pi))
    sw = (delta_cmd - plant.offset_rad) / plant.scale
    sw = np.deg2rad(sn.steer_angle_sensor_deg(np.rad2deg(sw)))  # what the sensor can read
    s = np.array([0.0, 0.0, psi0, v0_mps])
    states = np.zeros((n, 4))
    delta = np.zeros(n)
    acc = np.zeros(n)
    u_all = np.zeros((n, 3))
    doff = 0.0
    zone = None
    sq = math.sqrt(dt_s)
    lo, hi = v_range_mps
    for i in range(n):
        states[i] = s
        a = a_des[i] + 1.0 * max(lo - s[3], 0.0) - 1.0 * max(s[3] - hi, 0.0)
        z = plant.select_zone(float(s[3]), zone)
        base = plant.z_offset[z]
        if a >= base:
            ap, bp = min((a - base) / plant.z_scale[z], 1.0), 0.0
        else:
            ap, bp = 0.0, min((base - a) / plant.z_brake[z], 1.0)
        u = np.array([sw[i], ap, bp])
        u_all[i] = u
        u_eff = np.array([sw[i] + doff / plant.scale, ap, bp])
        delta[i] = plant.offset_rad + plant.scale * u_eff[0]
        extra = speed_walk_mps_rts / sq * rng_w.standard_normal() if speed_walk_mps_rts else 0.0
        r = plant.step(s, u_eff, dt_s, zone, extra)
        acc[i] = r.accel_mps2
        s, zone = r.state, r.zone
        if heading_walk_rad_rts:
            s[2] += heading_walk_rad_rts * sq * rng_w.standard_normal()
        if position_walk_m_rts:
            s[:2] += position_walk_m_rts * sq * rng_w.standard_normal(2)
        if delta_offset_walk_rad_rts:
            doff += delta_offset_walk_rad_rts * sq * rng_w.standard_normal()
    return TruthTrajectory(np.arange(n) * dt_s, states, sw, delta, acc, u_all)
