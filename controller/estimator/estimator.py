"""State estimator shared by simulate, drive and replay: :class:`Estimator`, the extended Kalman
filter of controller/estimator/ekf.py fed messages as they arrive, GNSS late.

Inputs, each at its own rate (call the ``update_*`` methods as messages arrive):

- :meth:`Estimator.predict` ``(t_s, u)``: the plant input ``[steering_wheel_angle_rad,
  accel_pedal, brake_pedal]`` from ``t_s`` on (the controller's applied command). The CAN
  steering-wheel angle, when fresher than ``steer_input_max_age_s``, replaces ``u[0]``: it
  is what the wheels follow.
- :meth:`Estimator.update_can`: the four wheel speeds (their mean is the speed; optionally
  the rear difference is a second, gyro-bias-free yaw rate, the report's eq. 5),
  steering-wheel angle, CAN yaw rate.
- :meth:`Estimator.update_imu`: gyro yaw rate, longitudinal acceleration. The CAN
  (KINEMATICS) and IMU yaw rates share the one ``gyro_bias_radps`` state: feed one of them (a
  car with both has two biases, which this filter does not separate).
- :meth:`Estimator.update_gnss` ``(t_meas_s, t_now_s, ...)``: position, heading, speed,
  measured at ``t_meas_s`` and arriving at ``t_now_s``.

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

Allocation: the log's buffers are allocated once in ``__init__``; what is still allocated per
event is the log's tuples (the event, the held inputs after it).
"""

from __future__ import annotations

import bisect
import math
from typing import Any

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import IAP, IBP, ISW

from hmpc.controller.estimator.config import IBR, IDOFF, IKWS, IV, NXE, STATE_NAMES, EstimatorConfig
from hmpc.controller.estimator.ekf import (
    EVENT_CAN,
    EVENT_GNSS,
    EVENT_IMU,
    EVENT_TICK,
    Ekf,
    float_view,
)


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


class Estimator(Ekf):
    """Extended Kalman filter over the plant state (:class:`Ekf`) with the message API and
    the event log; see the module docstring.

    Args:
        params: the controller's model (geometry, steering map, zones).
        config: noise and settings.

    Before the first GNSS fix with position and heading (or :meth:`reset`) the filter has no
    state: ``initialized`` is False and :meth:`state` raises.
    """

    def __init__(self, params: Params, config: EstimatorConfig | None = None):
        super().__init__(params, config)
        cfg = self.cfg
        # event log: time-ordered. Per event (kind, t, 4 payload values) and the held inputs
        # after it as tuples in fixed-length lists; state and covariance after it in arrays.
        n = cfg.history_events
        self._ev_n, self._ev_cap = 0, n
        self._ev: list[Any] = [None] * n  # (kind, t, p0, p1, p2, p3) per event
        self._ev_t = [0.0] * n
        self._ev_aux: list[Any] = [None] * n  # the held inputs after each event
        self._ev_x = np.zeros((n, NXE))
        self._ev_P = np.zeros((n, NXE, NXE))
        self._ev_xm = float_view(self._ev_x.reshape(-1))
        self._ev_Pm = float_view(self._ev_P.reshape(-1))
        self.initialized = False
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
        self._log(EVENT_TICK, self._t, self._u[0], self._u[1], self._u[2], math.nan)

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

    def model_inputs(self) -> tuple[float, float]:
        """(speed [m/s], gyro bias [rad/s]) now, as Python floats (what the online model
        estimator, controller/adapt, reads each control step); NaN before the first fix."""
        if not self.initialized:
            return math.nan, math.nan
        return self._xm[IV], self._xm[IBR]

    def steering_correction_rad(self) -> float:
        """The filter's correction to eq. 7's road-wheel angle now (``delta_offset_rad``) [rad],
        a Python float; 0.0 before the first fix (its prior). What the MPC's offset-free
        steering reads (``MpcController.use_steering_correction``)."""
        if not self.initialized:
            return 0.0
        return float(self._xm[IDOFF])

    def use_model(self, model) -> None:
        """Predict with new model values (``controller.adapt.LearnedModel``): eq. 7's offset
        and scale, eq. 8 per zone. The road-wheel angle the filter holds is kept: the change of
        eq. 7 at the current steering-wheel angle is taken out of ``delta_offset_rad`` (in the
        event log too, so that a late GNSS fix replays consistently), so the learned map and the
        filter's own offset correction never count one error twice."""
        off, sc = float(model.offset_rad), float(model.scale)
        if self.initialized:
            sw = self._steer(self._t)
            d = (self._off + self._scale * sw) - (off + sc * sw)
            self._x[IDOFF] += d
            n = self._ev_n
            if n:
                self._ev_x[:n, IDOFF] += d
        self._off, self._scale = off, sc
        self._geometry = (off, sc, self._b)
        pl = self.plant
        pl.offset_rad, pl.scale = off, sc
        pl.z_offset[:] = model.zone_offset_mps2
        pl.z_scale[:] = model.zone_scale_mps2
        pl.z_brake[:] = model.zone_brake_mps2
        self._eq8[:] = zip(pl.z_offset.tolist(), pl.z_scale.tolist(), pl.z_brake.tolist())

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
        if not (
            math.isfinite(t_s) and math.isfinite(u0) and math.isfinite(u1) and math.isfinite(u2)
        ):
            raise ValueError(f"predict needs a finite time and input, got t_s={t_s!r}, u={u!r}")
        if not self.initialized:
            self._u[:] = (u0, u1, u2)
            self._t = max(self._t, float(t_s))
            return
        t = max(float(t_s), self._t)
        self._apply(EVENT_TICK, t, u0, u1, u2, math.nan)
        self._log(EVENT_TICK, t, u0, u1, u2, math.nan)

    def update_can(
        self,
        t_s: float,
        wheel_speeds_mps=None,
        steering_wheel_angle_rad=None,
        yaw_rate_radps=None,
        speed_mps=None,
    ) -> None:
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
        self._apply(EVENT_CAN, t, ws_mean, sw, yaw, wheel_yaw)
        self._log(EVENT_CAN, t, ws_mean, sw, yaw, wheel_yaw)

    def update_imu(self, t_s: float, yaw_rate_radps=None, accel_x_mps2=None) -> None:
        """An IMU sample: yaw rate [rad/s] (gyro), longitudinal acceleration [m/s^2]. None or
        a non-finite value: absent."""
        t_s = _time(t_s)
        if not self.initialized:
            return
        yaw, ax = _value(yaw_rate_radps), _value(accel_x_mps2)
        t = max(t_s, self._t)
        self._apply(EVENT_IMU, t, yaw, ax, math.nan, math.nan)
        self._log(EVENT_IMU, t, yaw, ax, math.nan, math.nan)

    def update_gnss(
        self,
        t_meas_s: float,
        t_now_s: float | None = None,
        x_m=None,
        y_m=None,
        heading_rad=None,
        speed_mps=None,
    ) -> bool:
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
                v0 = (
                    v
                    if v == v
                    else (self._last_speed if self._last_speed == self._last_speed else 0.0)
                )
                self.reset(t_meas, (x, y, h, v0))  # keeps the held inputs
                self._count("gnss", True)
                return True
            return False
        if t_meas >= self._t:
            ok = self._apply(EVENT_GNSS, t_meas, x, y, h, v)
            self._log(EVENT_GNSS, t_meas, x, y, h, v)
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
            self.update_can(
                m.t_meas_s,
                v.get("wheel_speeds_mps"),
                v.get("steering_wheel_angle_rad"),
                v.get("yaw_rate_radps"),
                v.get("speed_mps"),
            )
        elif m.kind == "imu":
            self.update_imu(m.t_meas_s, v.get("yaw_rate_radps"), v.get("accel_x_mps2"))
        elif m.kind == "gnss":
            self.update_gnss(
                m.t_meas_s,
                m.t_arrival_s if t_now_s is None else t_now_s,
                v.get("x_m"),
                v.get("y_m"),
                v.get("heading_rad"),
                v.get("speed_mps"),
            )
        else:
            raise ValueError(f"unknown measurement kind {m.kind!r}")

    def _need_init(self) -> None:
        if not self.initialized:
            raise RuntimeError("the estimator has no state yet: no GNSS fix and no reset()")

    # ========================================================= event log, replay
    def _snapshot(self, i: int) -> None:
        """Record the filter after event ``i``: state and covariance into the preallocated
        arrays (flat memoryview copies), the held inputs as one tuple."""
        k = i * NXE
        self._ev_xm[k : k + NXE] = self._xm
        k *= NXE
        self._ev_Pm[k : k + NXE * NXE] = self._Pm
        u = self._u
        self._ev_aux[i] = (
            self._t,
            u[0],
            u[1],
            u[2],
            self._sw_meas,
            self._t_sw,
            self._a_imu,
            self._t_aimu,
            self._zone,
        )

    def _restore(self, i: int) -> None:
        """Rewind the filter to just after event ``i``."""
        self._x[:] = self._ev_x[i]
        self._P[:] = self._ev_P[i]
        (self._t, u0, u1, u2, self._sw_meas, self._t_sw, self._a_imu, self._t_aimu, self._zone) = (
            self._ev_aux[i]
        )
        self._u[0], self._u[1], self._u[2] = u0, u1, u2

    def _make_room(self) -> None:
        """When the log is full, drop its oldest half (the copies do not overlap)."""
        n, cap = self._ev_n, self.cfg.history_events
        if n < cap:
            return
        h = cap // 2
        m = n - h
        a: Any
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
        ev[i + 1 : n + 1] = ev[i:n]
        self._ev_t[i + 1 : n + 1] = self._ev_t[i:n]
        ev[i] = (EVENT_GNSS, t_meas, gx, gy, gh, gv)
        self._ev_t[i] = t_meas
        self._ev_n = n + 1
        self._restore(i - 1)
        ok = self._apply(EVENT_GNSS, t_meas, gx, gy, gh, gv)
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
