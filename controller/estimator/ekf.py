"""State estimator shared by simulate, drive and replay: an extended Kalman filter over the plant.

State (7): the plant's ``[x_m, y_m, psi_rad, v_mps]`` (``models.plant``: local ENU, the
front-wheel point of eq. 1) augmented with three slowly varying sensor/model errors that the
car's own data make observable and that otherwise bias the plant state:

- ``delta_offset_rad``: a correction to eq. 7's road-wheel angle (``delta = offset + scale *
  sw + delta_offset``). It absorbs a steering map known only to +-13 % (the comma minute) and
  understeer at speed; the gyro observes it through the yaw rate ``v sin(delta) / b``.
- ``gyro_bias_radps``: the yaw-rate sensor's bias (the simulator draws up to +-0.002 rad/s).
  Separable from ``delta_offset`` because it does not scale with speed and GNSS heading sees
  the integral of the true yaw rate.
- ``wheel_speed_scale``: tyre rolling radius error (wheel speeds read ``scale * v``; the comma
  minute's wheel mean reads 0.8 % below GNSS). GNSS speed and position observe it; it keeps
  speed honest through a GNSS outage.

Process model: the report's eq. 1 + eq. 7 + eq. 8 of ``models.plant``, the one place they
are written: ``HybridPlant.step`` for the mean (zone hysteresis, exact in speed, standstill
clamp) and ``bicycle_jacobian`` for the covariance. The prediction runs a few hundred times a
second, so both are written out in :meth:`Estimator._propagate` on Python floats, operation
for operation, with the plant's zone lists and eq. 8 coefficients
(``tests/test_estimator_speed.py`` holds them to the plant: the mean to the bit, ``F`` to
``HybridPlant.jacobians``); a plant with opt-in extensions is stepped by ``HybridPlant.step``
itself. The ``delta_offset`` state enters by folding it into the steering input, ``sw +
delta_offset / scale``; eq. 1's derivative with respect to the road-wheel angle is its
column of ``F``.
When the IMU supplies a longitudinal acceleration it replaces eq. 8 in the speed propagation
(``use_imu_accel``). Propagation sub-steps are at most ``max_step_s``; the three extra states
are random walks. The covariance is propagated with ``F = I + A dt`` and a diagonal process
noise (random-walk densities in :class:`EstimatorConfig`).

Inputs, each at its own rate (call the ``update_*`` methods as messages arrive):

- :meth:`predict` ``(t_s, u)``: the plant input ``[steering_wheel_angle_rad, accel_pedal,
  brake_pedal]`` from ``t_s`` on (the controller's applied command). The CAN steering-wheel
  angle, when fresher than ``steer_input_max_age_s``, replaces ``u[0]``: it is what the
  wheels follow.
- :meth:`update_can`: the four wheel speeds (their mean is the speed; optionally the rear
  difference is a second, gyro-bias-free yaw rate, the report's eq. 5), steering-wheel angle,
  CAN yaw rate.
- :meth:`update_imu`: gyro yaw rate, longitudinal acceleration. The CAN (KINEMATICS) and IMU
  yaw rates share the one ``gyro_bias_radps`` state: feed one of them (a car with both has
  two biases, which this filter does not separate).
- :meth:`update_gnss` ``(t_meas_s, t_now_s, ...)``: position, heading, speed, measured at
  ``t_meas_s`` and arriving at ``t_now_s``.

Latency compensation (GNSS): every event the filter processes (predict ticks, CAN, IMU, GNSS)
is kept in a time-ordered log with the state, covariance and held inputs after it
(``history_events`` deep, allocated once; when full the oldest half is dropped). A fix
measured in the past is inserted at its measurement time: the filter is rewound to the last
event before it, the fix is applied at ``t_meas_s``, and every later event is re-applied (and
its snapshot rewritten, so a later delayed fix sees this one). The result is the one the filter
would have had with the fix on time (the tests check it is equal to rounding), not an
approximation of it, at the cost of re-running the events of one latency (about 25 events for
100 ms). CAN and IMU messages are applied when they arrive, at the
filter's current time if they are stamped earlier (their latency is under a CAN period); their
stamps are recorded, so a rewind re-applies them in arrival order. A fix older than the log
is rejected and counted (``too_old``).

Outliers: every update is gated on its normalised innovation squared ``y' S^-1 y`` against the
chi-square quantile with the update's degrees of freedom at ``gate_probability`` (0.999: a
consistent filter rejects 1 in 1000 good measurements; a 10 m jump on 2 cm GNSS scores about
10^5 against a threshold of 18.5 for a four-value fix). Rejections are counted per sensor in
:attr:`Estimator.stats`. After ``gnss_reinit_after`` consecutive rejected fixes the filter
trusts GNSS again (the fix, not the filter, was right: e.g. after a long outage the
dead-reckoned state drifted): position and heading are reset to the fix with the initial
uncertainty, counted as ``reinit``.

Allocation and cost: the filter, Jacobian, measurement and log buffers are allocated once in
``__init__``; a step writes into them (flat ``memoryview`` s give their elements as Python
floats). Per event: ``P = F P F'`` is two 7x7 products and the process noise one BLAS
``daxpy`` on P's diagonal; a one-value update (CAN speed, yaw rate) is ``P h``, one ``ddot``,
``daxpy`` for the state and ``dger`` for ``P -= PH' HP / s``, all in place (P symmetric to a
few ulps; each GNSS update symmetrises it exactly); a GNSS update solves ``S^-1 [H P | y]``
by Cholesky (LAPACK ``dposv``). What is still allocated per event: the log's tuples (the
event, the held inputs after it) and the GNSS update's few small products. ``tools/bench_mpc.py`` prints the
estimator's time per control period.

Also here: :func:`estimate_recording` (the estimator over a canonical
recording's raw channels, e.g. the real comma2k19 minute; ``tools/estimate_plot.py`` plots it).
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg.blas import daxpy, ddot, dger
from scipy.linalg.lapack import dposv
from scipy.stats import chi2

from hmpc.models.params import Params
from hmpc.models.plant import IAP, IBP, ISW, HybridPlant
from hmpc.models.zones import zone_with_hysteresis

NXE = 7  #: estimator state size
IX, IY, IPSI, IV, IDOFF, IBR, IKWS = range(NXE)
STATE_NAMES = ("x_m", "y_m", "psi_rad", "v_mps", "delta_offset_rad", "gyro_bias_radps",
               "wheel_speed_scale")

_TICK, _CAN, _IMU, _GNSS = 0, 1, 2, 3
SENSORS = ("can_speed", "wheel_yaw_rate", "can_yaw_rate", "imu_yaw_rate", "gnss")


@dataclass(frozen=True)
class EstimatorConfig:
    """Noise model and settings of :class:`Estimator`; every number is 1-sigma and SI.

    Random-walk densities are per square root of a second: over ``dt`` the state's variance
    grows by ``density**2 * dt``.
    """

    #: eq. 8's error as a speed random walk [m/s/sqrt(s)]: on the comma minute the high zone
    #: leaves about half the acceleration variance unexplained (NMSE 48 %), ~0.3 m/s^2 rms.
    speed_walk_mps_rts: float = 0.5
    #: the same when the IMU's acceleration drives the speed (accelerometer noise 0.05 m/s^2,
    #: bias up to 0.02 m/s^2, grade) [m/s/sqrt(s)].
    speed_walk_imu_mps_rts: float = 0.1
    #: heading error of eq. 1 beyond a steering offset (slip, road camber) [rad/sqrt(s)].
    heading_walk_rad_rts: float = 0.005
    #: position error of eq. 1 (side slip of the front point) [m/sqrt(s)].
    position_walk_m_rts: float = 0.02
    #: drift of the road-wheel angle correction [rad/sqrt(s)] (understeer changes with speed
    #: and lateral acceleration within seconds).
    delta_offset_walk_rad_rts: float = 0.001
    #: gyro bias drift [rad/s/sqrt(s)]: wanders about 0.001 rad/s in an hour, as a MEMS
    #: gyro's bias does with temperature.
    gyro_bias_walk_radps_rts: float = 2e-5
    #: tyre radius drift (load, pressure, temperature) [1/sqrt(s)].
    wheel_scale_walk_rts: float = 1e-4

    #: initial uncertainty (after the first fix or :meth:`Estimator.reset`).
    init_position_m: float = 0.5
    init_heading_rad: float = 0.05
    init_speed_mps: float = 0.5
    init_delta_offset_rad: float = 0.005
    init_gyro_bias_radps: float = 0.003
    init_wheel_scale: float = 0.02

    #: measurement noise; the defaults match ``models.sim.live_sensors.SensorConfig()``
    #: (see :meth:`matching`).
    can_speed_mps: float = 0.05
    wheel_yaw_rate_radps: float = 0.035  # comma minute, rear difference against the gyro
    can_yaw_rate_radps: float = 0.005
    imu_yaw_rate_radps: float = 0.005
    gnss_position_m: float = 0.02
    gnss_heading_rad: float = math.radians(0.1)
    gnss_speed_mps: float = 0.05
    #: GNSS point relative to the eq. 1 point (front-axle centre), body axes (x fwd, y left)
    #: [m]. A conventions ``nav_lever_arm_m`` [lx, ly] from the rear axle is (lx - b, ly).
    gnss_offset_m: tuple[float, float] = (0.0, 0.0)

    #: use the rear wheel-speed difference as a yaw-rate measurement (report's eq. 5). Off by
    #: default: on the comma minute it differs from the gyro by 0.034 rad/s rms with heavy tails
    #: and a -0.009 rad/s offset (left/right tyre radii differ), which no state here models; it
    #: earns its place on a car without a yaw-rate sensor.
    use_wheel_yaw_rate: bool = False
    #: the IMU's longitudinal acceleration replaces eq. 8 while fresher than this [s].
    use_imu_accel: bool = True
    imu_accel_max_age_s: float = 0.05
    #: the CAN steering-wheel angle replaces the commanded one while fresher than this [s].
    steer_input_max_age_s: float = 0.1
    #: innovation gate: chi-square probability (see module docstring).
    gate_probability: float = 0.999
    #: consecutive rejected GNSS fixes before the filter re-initialises on GNSS.
    gnss_reinit_after: int = 20
    #: longest propagation sub-step [s] (the plant's step is exact in speed and heading for
    #: held inputs, midpoint in position: about dist * dpsi^2 / 24, 0.1 mm per 20 ms step at
    #: 20 m/s on a 5 m radius).
    max_step_s: float = 0.02
    #: depth of the event log for latency compensation (about 300 events/s: 1.7-3.4 s).
    history_events: int = 1024

    def __post_init__(self):
        if not 0.5 < self.gate_probability < 1.0:
            raise ValueError("gate_probability must be within (0.5, 1), got "
                             f"{self.gate_probability}")
        if self.history_events < 16:
            raise ValueError("history_events must be at least 16")
        if not self.max_step_s > 0:
            raise ValueError("max_step_s must be positive")

    @classmethod
    def matching(cls, sensors, **overrides) -> "EstimatorConfig":
        """Measurement noise matched to a ``live_sensors.SensorConfig`` (noise_scale applied)."""
        k = sensors.noise_scale
        quant = 0.01 / 3.6 / math.sqrt(12.0)  # WHEEL_SPEEDS 0.01 km/h step
        wheel = math.hypot(k * sensors.wheel_jitter_mps, quant)
        track = 1.6  # nominal; only sets a noise level
        kw = dict(can_speed_mps=math.hypot(k * sensors.speed_noise_mps, wheel / 2.0),
                  wheel_yaw_rate_radps=math.sqrt(2.0) * wheel / track,
                  can_yaw_rate_radps=k * sensors.can_yaw_rate_noise_radps,
                  imu_yaw_rate_radps=k * sensors.gyro_noise_radps,
                  gnss_position_m=max(k * sensors.position_noise_m, 1e-4),
                  gnss_heading_rad=max(k * sensors.heading_noise_rad, 1e-5),
                  gnss_speed_mps=max(k * sensors.gnss_speed_noise_mps, 1e-3))
        kw.update(overrides)
        return cls(**kw)


def _value(v) -> float:
    """A measurement value: None and non-finite numbers are absent (NaN)."""
    if v is None:
        return math.nan
    v = float(v)
    return v if math.isfinite(v) else math.nan


def _time(t_s) -> float:
    t = float(t_s)
    if not math.isfinite(t):
        raise ValueError(f"a message time must be finite, got {t_s!r}")
    return t


def _zone_bands(v_min_mps, v_max_mps, hysteresis_mps: float) -> list[tuple[float, float]]:
    """Per zone, the speeds [m/s] for which ``models.zones.zone_with_hysteresis(v, zone, ...,
    clamp=True)`` keeps ``zone`` (its band widened by the hysteresis; the first zone has no
    lower edge, the last none above). A cache of that rule's first test: outside the band the
    estimator calls the rule itself (``tests/test_estimator_speed.py`` checks they agree)."""
    n = len(v_max_mps)
    return [(-math.inf if z == 0 else v_min_mps[z] - hysteresis_mps,
             v_max_mps[z] + hysteresis_mps if z < n - 1 else math.inf) for z in range(n)]


class Estimator:
    """Extended Kalman filter over the plant state; see the module docstring.

    Args:
        params: the controller's model (geometry, steering map, zones).
        config: noise and settings.

    Before the first GNSS fix with position and heading (or :meth:`reset`) the filter has no
    state: ``initialized`` is False and :meth:`state` raises.
    """

    def __init__(self, params: Params, config: EstimatorConfig | None = None):
        if not params.is_model:
            raise ValueError("the estimator needs a parameter file with steering and zones")
        self.params = params
        self.cfg = cfg = config or EstimatorConfig()
        self.plant = plant = HybridPlant(params)
        veh = params.vehicle
        self._b = float(veh.wheelbase_m)
        self._track_r = float(veh.track_rear_m if veh.track_rear_m is not None
                              else veh.track_front_m)
        self._off = float(params.steering.offset_rad)
        self._scale = float(params.steering.scale)
        self._lever = (float(cfg.gnss_offset_m[0]), float(cfg.gnss_offset_m[1]))
        self._gate = {m: float(chi2.ppf(cfg.gate_probability, m)) for m in range(1, 5)}
        self._gate1 = self._gate[1]
        # the plant's zones and eq. 8 as Python floats for the scalar prediction (plant.py's
        # own lists); a plant with opt-in extensions is stepped by HybridPlant.step itself
        self._zone_args = (plant._v_min_list, plant._v_max_list, plant.hysteresis_mps)
        self._zone_keep = _zone_bands(*self._zone_args)
        self._eq8 = plant._eq8
        self._plant_step = getattr(plant, "ext", None) is not None
        self._max_step = float(cfg.max_step_s)
        self._sw_age = float(cfg.steer_input_max_age_s)
        self._imu_age = float(cfg.imu_accel_max_age_s) if cfg.use_imu_accel else -math.inf
        # filter buffers
        self._x = np.zeros(NXE)
        self._P = np.zeros((NXE, NXE))
        self._F = np.eye(NXE)
        self._FT = self._F.T  # a view: F' for P = F P F'
        self._PT = self._P.T  # a view: P in Fortran order, for BLAS's in-place rank-one update
        self._Pflat = self._P.reshape(-1)  # a view: its diagonal is every NXE + 1-th element
        # flat float views of x, P, F: element access on Python floats, without numpy scalars
        self._xm = memoryview(self._x)
        self._Pm = memoryview(self._Pflat)
        self._Fm = memoryview(self._F.reshape(-1))
        self._geometry = (self._off, self._scale, self._b)  # eq. 7 offset, scale; wheelbase
        self._tmp = np.zeros((NXE, NXE))
        self._u4 = np.zeros(3)
        self._prediction_buffers = (self._F, self._FT, self._Fm, self._P, self._tmp, self._Pflat)
        self._q = np.array([cfg.position_walk_m_rts, cfg.position_walk_m_rts,
                            cfg.heading_walk_rad_rts, cfg.speed_walk_mps_rts,
                            cfg.delta_offset_walk_rad_rts, cfg.gyro_bias_walk_radps_rts,
                            cfg.wheel_scale_walk_rts]) ** 2
        self._q_imu_v = cfg.speed_walk_imu_mps_rts ** 2
        self._q_imu = self._q.copy()  # the same with the IMU driving the speed
        self._q_imu[IV] = self._q_imu_v
        self._diag = self._P.reshape(-1)[:: NXE + 1]  # a view on P's diagonal
        self._init_var = np.array([cfg.init_position_m, cfg.init_position_m, cfg.init_heading_rad,
                                   cfg.init_speed_mps, cfg.init_delta_offset_rad,
                                   cfg.init_gyro_bias_radps, cfg.init_wheel_scale]) ** 2
        # update buffers per dimension m = 1..4 (GNSS)
        self._H = {m: np.zeros((m, NXE)) for m in range(1, 5)}
        self._PHt = {m: np.zeros((NXE, m)) for m in range(1, 5)}
        self._S = {m: np.zeros((m, m)) for m in range(1, 5)}
        self._S_diag = {m: self._S[m].reshape(-1)[:: m + 1] for m in range(1, 5)}  # views
        self._B = {m: np.zeros((m, NXE + 1)) for m in range(1, 5)}  # [H P | y]
        self._half = np.full((), 0.5)  # a 0-d array: a Python float in a ufunc costs more
        self._y = {m: np.zeros(m) for m in range(1, 5)}
        self._R = {m: np.zeros(m) for m in range(1, 5)}
        self._Hm = {m: memoryview(self._H[m].reshape(-1)) for m in range(1, 5)}
        self._ym = {m: memoryview(self._y[m]) for m in range(1, 5)}
        self._Rm = {m: memoryview(self._R[m]) for m in range(1, 5)}
        # one-value updates: a row H per measurement (its zeros never change; its other
        # elements written through a memoryview) and P H'
        self._h_speed = np.zeros(NXE)                  # IV, IKWS, IDOFF
        self._h_yaw = np.zeros(NXE)                    # IV, IDOFF; IBR = 1
        self._h_yaw[IBR] = 1.0
        self._h_wyaw = np.zeros(NXE)                   # IV, IDOFF, IKWS
        self._hm_speed, self._hm_yaw, self._hm_wyaw = (memoryview(h) for h in (
            self._h_speed, self._h_yaw, self._h_wyaw))
        self._ph1 = np.zeros(NXE)
        self._r_speed = cfg.can_speed_mps ** 2
        # event log: time-ordered. Per event (kind, t, 4 payload values) and the held inputs
        # after it as tuples in fixed-length lists; state and covariance after it in arrays.
        n = cfg.history_events
        self._ev_n, self._ev_cap = 0, n
        self._ev = [None] * n
        self._ev_t = [0.0] * n
        self._ev_aux = [None] * n
        self._ev_x = np.zeros((n, NXE))
        self._ev_P = np.zeros((n, NXE, NXE))
        self._ev_xm = memoryview(self._ev_x.reshape(-1))
        self._ev_Pm = memoryview(self._ev_P.reshape(-1))
        self.stats = {s: {"accepted": 0, "rejected": 0} for s in SENSORS}
        self.stats["gnss"].update(too_old=0, replays=0, reinit=0, latency_max_s=0.0)
        self._counting = True
        self.initialized = False
        self._clear_held()

    def _clear_held(self) -> None:
        self._t = -math.inf
        self._u = [0.0, 0.0, 0.0]
        self._sw_meas, self._t_sw = 0.0, -math.inf
        self._a_imu, self._t_aimu = 0.0, -math.inf
        self._zone: int | None = None
        self._gnss_rejects = 0
        self._last_speed = math.nan

    # =================================================================== public API
    def reset(self, t_s: float, state, sigmas=None) -> None:
        """Start (or restart) at ``t_s`` from plant ``state`` (x, y, psi, v) or a 7-state.

        ``sigmas``: initial 1-sigma per state (7); default the config's ``init_*``.
        """
        s = np.asarray(state, dtype=float).reshape(-1)
        if len(s) not in (4, NXE) or not np.all(np.isfinite(s)):
            raise ValueError(f"reset needs a finite 4- or 7-state, got {state!r}")
        if sigmas is not None and len(sigmas) != NXE:
            raise ValueError(f"reset needs 7 sigmas ({', '.join(STATE_NAMES)})")
        self._x[:] = 0.0
        self._x[IKWS] = 1.0
        self._x[: len(s)] = s
        self._P[:] = 0.0
        if sigmas is None:
            self._diag[:] = self._init_var
        else:
            self._diag[:] = np.asarray(sigmas, dtype=float) ** 2
        self._t = float(t_s)
        self._zone = self.plant.select_zone(float(self._x[IV]), None)
        self._gnss_rejects = 0
        self._ev_n = 0
        self.initialized = True
        self._log(_TICK, self._t, self._u[0], self._u[1], self._u[2], math.nan)

    @property
    def time_s(self) -> float:
        """Time of the filter's state [s] (the latest event applied)."""
        return self._t

    def state(self) -> np.ndarray:
        """Plant state estimate ``[x_m, y_m, psi_rad, v_mps]`` at :attr:`time_s` (a copy)."""
        self._need_init()
        return self._x[:4].copy()

    def covariance(self) -> np.ndarray:
        """Covariance of :meth:`state` (4x4, a copy)."""
        self._need_init()
        return self._P[:4, :4].copy()

    def full_state(self) -> np.ndarray:
        """All 7 states (``STATE_NAMES``), a copy."""
        self._need_init()
        return self._x.copy()

    def full_covariance(self) -> np.ndarray:
        """Covariance of :meth:`full_state` (7x7, a copy)."""
        self._need_init()
        return self._P.copy()

    def predict(self, t_s: float, u=None) -> None:
        """Propagate to ``t_s`` with the inputs held so far, then hold ``u`` (steering-wheel
        angle [rad], accel pedal, brake pedal) from ``t_s`` on (None: keep the held input).

        Raises:
            ValueError: a non-finite time or input.
        """
        if u is None:
            u0, u1, u2 = self._u
        else:
            u0, u1, u2 = float(u[ISW]), float(u[IAP]), float(u[IBP])
        if not (math.isfinite(t_s) and math.isfinite(u0) and math.isfinite(u1)
                and math.isfinite(u2)):
            raise ValueError(f"predict needs a finite time and input, got t_s={t_s!r}, u={u!r}")
        if not self.initialized:
            self._u[:] = (u0, u1, u2)
            self._t = max(self._t, float(t_s))
            return
        t = max(float(t_s), self._t)
        self._apply(_TICK, t, u0, u1, u2, math.nan)
        self._log(_TICK, t, u0, u1, u2, math.nan)

    def update_can(self, t_s: float, wheel_speeds_mps=None, steering_wheel_angle_rad=None,
                   yaw_rate_radps=None, speed_mps=None) -> None:
        """A CAN message (or several of one instant): any of the four wheel speeds (fl, fr, rl,
        rr) [m/s], or their mean ``speed_mps``; the steering-wheel angle [rad]; the yaw rate
        [rad/s] (KINEMATICS). Stamped earlier than :attr:`time_s`: applied now. None or a
        non-finite value: absent (a dropout)."""
        t_s = _time(t_s)
        ws_mean = wheel_yaw = math.nan
        if wheel_speeds_mps is not None:
            fl, fr, rl, rr = wheel_speeds_mps
            rl, rr = _value(rl), _value(rr)
            ws_mean = 0.25 * (_value(fl) + _value(fr) + rl + rr)
            if self.cfg.use_wheel_yaw_rate:
                wheel_yaw = (rr - rl) / self._track_r
        elif speed_mps is not None:
            ws_mean = _value(speed_mps)
        sw = _value(steering_wheel_angle_rad)
        yaw = _value(yaw_rate_radps)
        if not self.initialized:
            if sw == sw:
                self._sw_meas, self._t_sw = sw, t_s
            if ws_mean == ws_mean:
                self._last_speed = ws_mean
            return
        t = max(t_s, self._t)
        self._apply(_CAN, t, ws_mean, sw, yaw, wheel_yaw)
        self._log(_CAN, t, ws_mean, sw, yaw, wheel_yaw)

    def update_imu(self, t_s: float, yaw_rate_radps=None, accel_x_mps2=None) -> None:
        """An IMU sample: yaw rate [rad/s] (gyro), longitudinal acceleration [m/s^2]. None or
        a non-finite value: absent."""
        t_s = _time(t_s)
        if not self.initialized:
            return
        yaw, ax = _value(yaw_rate_radps), _value(accel_x_mps2)
        t = max(t_s, self._t)
        self._apply(_IMU, t, yaw, ax, math.nan, math.nan)
        self._log(_IMU, t, yaw, ax, math.nan, math.nan)

    def update_gnss(self, t_meas_s: float, t_now_s: float | None = None, x_m=None, y_m=None,
                    heading_rad=None, speed_mps=None) -> bool:
        """A GNSS/INS fix measured at ``t_meas_s`` arriving at ``t_now_s`` (default: the
        measurement time, no latency). Any of position (both ``x_m`` and ``y_m``), heading,
        speed. A fix older than the filter's time is applied at ``t_meas_s`` by rewinding
        (module docstring); the filter's time does not move to ``t_now_s`` (messages of the
        same instant may still come; :meth:`predict` moves it). ``t_now_s`` is checked and
        its lag recorded (``stats['gnss']['latency_max_s']``). Returns True when accepted
        (False: gated out, too old, or nothing in it).

        Raises:
            ValueError: ``t_now_s`` before ``t_meas_s`` (a fix from the future).
        """
        x, y = _value(x_m), _value(y_m)
        if not (x == x and y == y):
            x = y = math.nan
        h, v = _value(heading_rad), _value(speed_mps)
        t_meas = _time(t_meas_s)
        t_now = t_meas if t_now_s is None else _time(t_now_s)
        if not t_now >= t_meas - 1e-9:
            raise ValueError(f"a GNSS fix measured at {t_meas} s cannot arrive at {t_now} s")
        g = self.stats["gnss"]
        g["latency_max_s"] = max(g["latency_max_s"], t_now - t_meas)
        if not self.initialized:
            if x == x and h == h:
                v0 = v if v == v else (self._last_speed if self._last_speed == self._last_speed
                                       else 0.0)
                self.reset(t_meas, (x, y, h, v0))  # keeps the held inputs
                self._count("gnss", True)
                return True
            return False
        if t_meas >= self._t:
            ok = self._apply(_GNSS, t_meas, x, y, h, v)
            self._log(_GNSS, t_meas, x, y, h, v)
        else:
            ok = self._replay_with(t_meas, x, y, h, v)
            if ok is None:
                g["too_old"] += 1
                return False
        return bool(ok)

    def feed(self, m, t_now_s: float | None = None):
        """Apply one ``models.sim.live_sensors.Measurement`` (or anything with ``kind``,
        ``t_meas_s``, ``t_arrival_s`` and ``values``)."""
        v = m.values
        if m.kind == "can":
            self.update_can(m.t_meas_s, v.get("wheel_speeds_mps"),
                            v.get("steering_wheel_angle_rad"), v.get("yaw_rate_radps"),
                            v.get("speed_mps"))
        elif m.kind == "imu":
            self.update_imu(m.t_meas_s, v.get("yaw_rate_radps"), v.get("accel_x_mps2"))
        elif m.kind == "gnss":
            self.update_gnss(m.t_meas_s, m.t_arrival_s if t_now_s is None else t_now_s,
                             v.get("x_m"), v.get("y_m"), v.get("heading_rad"), v.get("speed_mps"))
        else:
            raise ValueError(f"unknown measurement kind {m.kind!r}")

    # ============================================================== the filter
    def _need_init(self) -> None:
        if not self.initialized:
            raise RuntimeError("the estimator has no state yet: no GNSS fix and no reset()")

    def _count(self, sensor: str, ok: bool) -> None:
        if self._counting:
            self.stats[sensor]["accepted" if ok else "rejected"] += 1

    def _steer(self, t: float) -> float:
        """Steering-wheel angle the wheels follow at ``t`` [rad]: the CAN angle while fresh."""
        if t - self._t_sw <= self._sw_age:
            return self._sw_meas
        return self._u[0]

    def _propagate_to(self, t: float) -> None:
        """Predict from :attr:`time_s` to ``t`` [s] in equal sub-steps of at most
        ``max_step_s``. The held inputs and their freshness (CAN steering angle, IMU
        acceleration) are those at the start, for every sub-step."""
        t0 = self._t
        dt_total = t - t0
        if dt_total <= 0.0:
            return
        n = max(int(math.ceil(dt_total / self._max_step - 1e-9)), 1)
        dt = dt_total / n
        sw = self._sw_meas if t0 - self._t_sw <= self._sw_age else self._u[0]
        imu = t0 - self._t_aimu <= self._imu_age
        for _ in range(n):
            self._propagate(dt, sw, imu)
        self._t = t

    def _propagate(self, dt: float, sw: float, imu: bool) -> None:
        """One prediction sub-step of ``dt`` [s] with the steering-wheel angle ``sw`` [rad]
        held; ``imu``: the IMU's acceleration replaces eq. 8's.

        The mean is ``HybridPlant.step`` (eq. 1, 7, 8; exact in speed, midpoint in heading and
        position, standstill clamp) written out here on Python floats, operation for
        operation (``tests/test_estimator_speed.py`` checks they agree to the bit); the
        covariance is ``F P F' + Q dt`` with eq. 1's Jacobian at the start of the step written
        into ``F`` (``bicycle_jacobian`` with respect to the road-wheel angle, which is also
        the derivative with respect to ``delta_offset``)."""
        xm = self._xm
        px, py, psi, v, doff = xm[IX], xm[IY], xm[IPSI], xm[IV], xm[IDOFF]
        ap, bp = self._u[1], self._u[2]
        zone = self._zone
        if zone is not None:
            lo, hi = self._zone_keep[zone]
            if not lo <= v <= hi:
                zone = zone_with_hysteresis(v, zone, *self._zone_args, clamp=True)
        else:
            zone = zone_with_hysteresis(v, zone, *self._zone_args, clamp=True)
        off_z, sc_z, br_z = self._eq8[zone]
        acc = off_z + sc_z * ap - br_z * bp  # eq. 8 (models.plant.zone_accel)
        extra = self._a_imu - acc if imu else 0.0
        off, scale, b = self._geometry
        u0 = sw + doff / scale
        delta = off + scale * u0  # eq. 7
        sd, cd = math.sin(delta), math.cos(delta)
        if self._plant_step:  # a plant with extensions: its own step
            u = self._u4
            u[0], u[1], u[2] = u0, ap, bp
            res = self.plant.step(self._x[:4], u, dt, zone, extra)
            self._x[:4] = res.state
            zone = res.zone
        else:
            a = acc + extra
            v0 = max(v, 0.0)
            v1 = v0 + a * dt
            if v1 < 0.0:  # stops within the step and stays stopped
                t_move = v0 / -a if a < 0 else 0.0
                v1 = 0.0
                dist = 0.5 * v0 * t_move
            else:
                dist = 0.5 * (v0 + v1) * dt
            dpsi = dist * sd / b
            ang = psi + 0.5 * dpsi + delta
            xm[IX] = px + dist * math.cos(ang)
            xm[IY] = py + dist * math.sin(ang)
            xm[IPSI] = psi + dpsi
            xm[IV] = v1
        self._zone = zone
        # F = I + A dt at the start of the step (flat index NXE * row + column); eq. 8's
        # speed row has no state in it
        c, s = math.cos(psi + delta), math.sin(psi + delta)
        F, FT, Fm, P, tmp, Pflat = self._prediction_buffers
        Fm[2] = Fm[4] = -v * s * dt           # x row: d/dpsi, d/ddelta_offset
        Fm[3] = c * dt                        # x row: d/dv
        Fm[9] = Fm[11] = v * c * dt           # y row: d/dpsi, d/ddelta_offset
        Fm[10] = s * dt                       # y row: d/dv
        Fm[17] = sd / b * dt                  # psi row: d/dv
        Fm[18] = v * cd / b * dt              # psi row: d/ddelta_offset
        F.dot(P, out=tmp)
        tmp.dot(FT, out=P)
        # P's diagonal += q dt, in place (every NXE + 1-th element of the flat P)
        daxpy(self._q_imu if imu else self._q, Pflat, NXE, dt, 0, 1, 0, NXE + 1)

    def _update(self, m: int, sensor: str, angle_row: int = -1) -> bool:
        """Gated update with ``self._H[m]``, ``self._y[m]`` (z - h), ``self._R[m]`` (variances).

        ``S = H P H' + R`` is factorised once (Cholesky, LAPACK ``dposv``) and solved for
        ``S^-1 [H P | y]``: the gain's transpose and ``S^-1 y`` without an inverse. A
        non-positive-definite ``S`` (a broken covariance) is a rejected measurement."""
        H, y, S, PHt, B, P = self._H[m], self._y[m], self._S[m], self._PHt[m], self._B[m], self._P
        if angle_row >= 0:
            y[angle_row] = math.remainder(y[angle_row], 2.0 * math.pi)
        P.dot(H.T, out=PHt)
        H.dot(PHt, out=S)
        np.add(self._S_diag[m], self._R[m], out=self._S_diag[m])
        B[:, :NXE] = PHt.T  # H P (P is symmetric)
        B[:, NXE] = y
        _, X, info = dposv(S, B)
        if info != 0:
            self._count(sensor, False)
            return False
        Si_y = X[:, NXE]
        if float(y.dot(Si_y)) > self._gate[m]:
            self._count(sensor, False)
            return False
        self._x += PHt.dot(Si_y)  # K y
        P -= PHt.dot(X[:, :NXE])  # K H P
        np.add(P, P.T, out=self._tmp)
        np.multiply(self._tmp, self._half, out=P)  # exactly symmetric again
        self._count(sensor, True)
        return True

    def _update1(self, h: np.ndarray, y: float, r: float, sensor: str) -> bool:
        """Gated one-value update: measurement row ``h``, innovation ``y`` (z - h(x)), noise
        variance ``r``. No inverse; the state and the rank-one covariance update ``P -= PH' HP
        / s`` in place by BLAS (positional arguments: f2py parses keywords slowly)."""
        ph = self._ph1
        self._P.dot(h, out=ph)
        s = ddot(h, ph) + r
        ok = y * y / s <= self._gate1
        if ok:
            daxpy(ph, self._x, NXE, y / s)  # x += K y
            dger(-1.0 / s, ph, ph, 1, 1, self._PT, 1, 1, 1)  # P -= PH' HP / s
        if self._counting:
            self.stats[sensor]["accepted" if ok else "rejected"] += 1
        return ok

    def _yaw_update(self, z: float, sigma: float, sensor: str, biased: bool) -> None:
        """A yaw-rate measurement ``z`` [rad/s] (1-sigma ``sigma``): eq. 1's ``v sin(delta)/b``,
        plus the gyro bias (``biased``) or times the wheel-speed scale (the wheels' yaw rate)."""
        xm = self._xm
        v, doff = xm[IV], xm[IDOFF]
        sw = self._sw_meas if self._t - self._t_sw <= self._sw_age else self._u[0]
        d = self._off + self._scale * sw + doff
        sd, cd = math.sin(d), math.cos(d)
        b = self._b
        if biased:
            h, hm = self._h_yaw, self._hm_yaw
            hm[IV] = sd / b
            hm[IDOFF] = v * cd / b
            y = z - (v * sd / b + xm[IBR])
        else:
            kws = xm[IKWS]
            h, hm = self._h_wyaw, self._hm_wyaw
            hm[IV] = kws * sd / b
            hm[IDOFF] = kws * v * cd / b
            hm[IKWS] = v * sd / b
            y = z - kws * v * sd / b
        self._update1(h, y, sigma * sigma, sensor)

    def _speed_update(self, t: float, z: float) -> None:
        """The mean wheel speed ``z`` [m/s] = scale * v (1 + cos delta) / 2 (front ~v, rear
        v cos delta)."""
        xm = self._xm
        v, doff, kws = xm[IV], xm[IDOFF], xm[IKWS]
        sw = self._sw_meas if t - self._t_sw <= self._sw_age else self._u[0]
        d = self._off + self._scale * sw + doff
        c = 0.5 * (1.0 + math.cos(d))
        hm = self._hm_speed
        hm[IV] = kws * c
        hm[IKWS] = v * c
        hm[IDOFF] = -0.5 * kws * v * math.sin(d)
        self._update1(self._h_speed, z - kws * v * c, self._r_speed, "can_speed")

    def _apply(self, kind: int, t: float, p0: float, p1: float, p2: float, p3: float):
        """Apply one event at time ``t`` (``t >= self._t``); the payload meaning by kind."""
        if t > self._t:
            self._propagate_to(t)
        if kind == _TICK:
            self._u[0], self._u[1], self._u[2] = p0, p1, p2
            return True
        cfg = self.cfg
        if kind == _CAN:
            if p1 == p1:
                self._sw_meas, self._t_sw = p1, t
            if p0 == p0:
                self._speed_update(t, p0)
            if p2 == p2:
                self._yaw_update(p2, cfg.can_yaw_rate_radps, "can_yaw_rate", True)
            if p3 == p3:
                self._yaw_update(p3, cfg.wheel_yaw_rate_radps, "wheel_yaw_rate", False)
            if self._x[IV] < 0.0:
                self._x[IV] = 0.0
            return True
        if kind == _IMU:
            if p0 == p0:
                self._yaw_update(p0, cfg.imu_yaw_rate_radps, "imu_yaw_rate", True)
            if p1 == p1:
                self._a_imu, self._t_aimu = p1, t
            return True
        return self._gnss_update(p0, p1, p2, p3)

    def _gnss_update(self, gx: float, gy: float, gh: float, gv: float) -> bool:
        """A fix's position [m] (at the lever arm), heading [rad] and speed [m/s] (NaN:
        absent) as one gated update; after ``gnss_reinit_after`` rejected fixes in a row the
        filter re-initialises on GNSS. Returns True when accepted."""
        cfg = self.cfg
        m = (2 if gx == gx else 0) + (1 if gh == gh else 0) + (1 if gv == gv else 0)
        if m == 0:
            return False
        self._H[m].fill(0.0)
        H, y, R = self._Hm[m], self._ym[m], self._Rm[m]  # flat views: H[NXE * row + column]
        xm = self._xm
        i = 0
        angle_row = -1
        if gx == gx:
            lx, ly = self._lever
            c, s = math.cos(xm[IPSI]), math.sin(xm[IPSI])
            H[IX] = 1.0
            H[NXE + IY] = 1.0
            H[IPSI] = -lx * s - ly * c
            H[NXE + IPSI] = lx * c - ly * s
            y[0] = gx - (xm[IX] + lx * c - ly * s)
            y[1] = gy - (xm[IY] + lx * s + ly * c)
            R[0] = R[1] = cfg.gnss_position_m ** 2
            i = 2
        if gh == gh:
            H[NXE * i + IPSI] = 1.0
            y[i] = gh - xm[IPSI]
            R[i] = cfg.gnss_heading_rad ** 2
            angle_row = i
            i += 1
        if gv == gv:
            H[NXE * i + IV] = 1.0
            y[i] = gv - xm[IV]
            R[i] = cfg.gnss_speed_mps ** 2
        ok = self._update(m, "gnss", angle_row)
        if ok:
            self._gnss_rejects = 0
        else:
            self._gnss_rejects += 1
            if self._gnss_rejects >= cfg.gnss_reinit_after and gx == gx:
                self._reinit_from_gnss(gx, gy, gh)
        return ok

    def _reinit_from_gnss(self, gx: float, gy: float, gh: float) -> None:
        x, P = self._x, self._P
        rows = [IX, IY] + ([IPSI] if gh == gh else [])
        lx, ly = self._lever
        if gh == gh:
            x[IPSI] = x[IPSI] + math.remainder(gh - x[IPSI], 2 * math.pi)
        c, s = math.cos(x[IPSI]), math.sin(x[IPSI])
        x[IX], x[IY] = gx - (lx * c - ly * s), gy - (lx * s + ly * c)
        for r in rows:
            P[r, :] = 0.0
            P[:, r] = 0.0
            P[r, r] = self._init_var[r]
        self._gnss_rejects = 0
        if self._counting:
            self.stats["gnss"]["reinit"] += 1

    # ========================================================= event log, replay
    def _snapshot(self, i: int) -> None:
        """Record the filter after event ``i``: state and covariance into the preallocated
        arrays (flat memoryview copies), the held inputs as one tuple."""
        k = i * NXE
        self._ev_xm[k:k + NXE] = self._xm
        k *= NXE
        self._ev_Pm[k:k + NXE * NXE] = self._Pm
        u = self._u
        self._ev_aux[i] = (self._t, u[0], u[1], u[2], self._sw_meas, self._t_sw, self._a_imu,
                           self._t_aimu, self._zone)

    def _restore(self, i: int) -> None:
        """Rewind the filter to just after event ``i``."""
        self._x[:] = self._ev_x[i]
        self._P[:] = self._ev_P[i]
        (self._t, u0, u1, u2, self._sw_meas, self._t_sw, self._a_imu, self._t_aimu,
         self._zone) = self._ev_aux[i]
        self._u[0], self._u[1], self._u[2] = u0, u1, u2

    def _make_room(self) -> None:
        """When the log is full, drop its oldest half (the copies do not overlap)."""
        n, cap = self._ev_n, self.cfg.history_events
        if n < cap:
            return
        h = cap // 2
        m = n - h
        for a in (self._ev, self._ev_t, self._ev_aux, self._ev_x, self._ev_P):
            a[:m] = a[h:n]
        self._ev_n = m

    def _log(self, kind: int, t: float, p0, p1, p2, p3) -> None:
        """Append the event just applied, with the filter after it."""
        if self._ev_n >= self._ev_cap:
            self._make_room()
        i = self._ev_n
        self._ev[i] = (kind, t, p0, p1, p2, p3)
        self._ev_t[i] = t
        self._snapshot(i)
        self._ev_n = i + 1

    def _replay_with(self, t_meas: float, gx, gy, gh, gv):
        """Insert a GNSS fix at ``t_meas`` into the log and re-run everything after it.
        Returns the update's result, or None when the log does not reach back that far
        (the fix is older than its first event's time)."""
        n = self._ev_n
        i = bisect.bisect_right(self._ev_t, t_meas, 0, n)
        if i == 0:
            return None
        self._make_room()
        if self._ev_n != n:  # room was made by dropping old events
            i -= n - self._ev_n
            n = self._ev_n
            if i <= 0:
                return None
        # shift the events i..n-1 up by one (their snapshots are all rewritten below)
        ev = self._ev
        ev[i + 1:n + 1] = ev[i:n]
        self._ev_t[i + 1:n + 1] = self._ev_t[i:n]
        ev[i] = (_GNSS, t_meas, gx, gy, gh, gv)
        self._ev_t[i] = t_meas
        self._ev_n = n + 1
        self._restore(i - 1)
        ok = self._apply(_GNSS, t_meas, gx, gy, gh, gv)
        self._snapshot(i)
        after_rejects = self._gnss_rejects
        self._counting = False
        apply, snapshot = self._apply, self._snapshot
        try:
            for k in range(i + 1, n + 1):
                apply(*ev[k])
                snapshot(k)
        finally:
            self._counting = True
        self._gnss_rejects = after_rejects
        self.stats["gnss"]["replays"] += 1
        return ok

# ============================================================ offline: a recording
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


def estimate_recording(rec, params: Params, config: EstimatorConfig | None = None, *,
                       tick_s: float = 0.02, gnss_latency_s: float = 0.0) -> EstimateRun:
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
        np.array_equal(w[0], wheels[0][0]) for w in wheels)
    if wheels_ok:
        events += [(t, 0, i, "wheels") for i, t in enumerate(wheels[0][0])]
    if sw is not None:
        events += [(t, 0, i, "sw") for i, t in enumerate(sw[0])]
    yaw_on_can = _source_of(rec, "yaw_rate") == "can"
    if yaw is not None:
        events += [(t, 1, i, "yaw") for i, t in enumerate(yaw[0])]
    imu_ax = ax is not None and yaw is not None and np.array_equal(ax[0], yaw[0]) \
        and _source_of(rec, "accel_x") != "can"
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
                est.update_gnss(t_meas, t, x, y, fin(None if gh_on is None else gh_on[i]),
                                fin(None if gv_on is None else gv_on[i]))
                counts["gnss"] += 1
        g = min(max(int(np.searchsorted(grid, tk, side="right")) - 1, 0), len(grid) - 1)
        u = (swg[g] if math.isfinite(swg[g]) else 0.0, ap[g] if math.isfinite(ap[g]) else 0.0,
             bp[g] if math.isfinite(bp[g]) else 0.0)
        est.predict(tk, u)
        if est.initialized:
            out_x[j] = est._x
            out_s[j] = np.sqrt(np.maximum(np.diag(est._P), 0.0))
    return EstimateRun(ticks, out_x, out_s, est.stats, counts)
