"""The online model estimator (:class:`ModelAdapter`): the learners fed, validity decided, and
the model the controller and the state estimator predict with (:class:`LearnedModel`).

Per control step, in this order, the loop calls:

1. :meth:`ModelAdapter.feed` (or ``signals.add_*``) for every sensor message as it arrives;
2. :meth:`ModelAdapter.learn` ``(t_s, v_mps, gyro_bias_radps)`` at the control instant, with
   the state estimator's speed and gyro bias: the period that just ended teaches the learners
   (steering map, the zone the car was in, the dead times and lags); returns a new
   :class:`LearnedModel` when a value in use moved by more than an immaterial amount (the
   loop hands it to the controller's and the estimator's ``use_model``), else None;
3. :meth:`ModelAdapter.commanded` with the command sent to the actuators.

A period's acceleration for eq. 8 is the accelerometer's (its bias against the speed's change
taken out) while the car runs straight, else the change of the estimator's speed: in a turn an
accelerometer away from eq. 1's front-axle point does not read that point's acceleration
(``AdaptConfig.long_imu_delta_max_rad``).

**Validity** (openpilot's ``valid`` flags): a filter's values (the steering map; a zone) are
used together once it has taken ``MIN_UPDATES`` samples, while none of them is at its bound
and its last samples agree with it; otherwise the file's values are used, and the change to
them is recorded as an event (:attr:`ModelAdapter.events`) that the command prints. Each value
also says whether it is ``identified`` (its 95 % interval within identification's
identifiability threshold). A dead time or lag is used only when its fit is valid and its 95 %
set excludes the file's value.

Cost: the learners work on Python floats and preallocated arrays; per control step some tens
of microseconds (``details.adaptation_details.cost_us`` of a run). What it reports is
``controller.adapt.report``'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hmpc.models.params import Params
from hmpc.models.plant import plant_extensions

from hmpc.controller.adapt.config import (
    KEY_LONG_DELAY,
    KEY_LONG_LAG,
    KEY_STEER_DELAY,
    KEY_STEER_LAG,
    KEY_STEER_OFFSET,
    KEY_STEER_SCALE,
    AdaptConfig,
    zone_key,
)
from hmpc.controller.adapt.longitudinal import ZoneLearner
from hmpc.controller.adapt.report import History, adaptation_counts, adaptation_report
from hmpc.controller.adapt.signals import PeriodSignals
from hmpc.controller.adapt.steering import OFFSET, SCALE, SteeringLearner
from hmpc.controller.adapt.timing import ResponseFit

#: [s] how often the dead-time and lag fits are evaluated (an argmin over their grids)
TIMING_EVERY_S = 1.0
#: [s] a changed model is looked for at most this often (a 50 Hz loop need not re-check its
#: model's validity and hand-over every step; the controller's own horizon is seconds)
PUSH_EVERY_S = 0.1
#: [s] the dead-time and lag fits' period: control periods are summed up to about this (a
#: 50 Hz loop feeds them at 10 Hz); with the grid's 0.05 s steps placed inside a period
#: exactly, it resolves dead times as lagd's 20 Hz does, at a fifth of the vector work
TIMING_PERIOD_S = 0.1
#: [1] an identified value stays identified while its 95 % half-width is within this many
#: times its threshold (hysteresis: the flag does not flicker with its interval)
VALID_HYSTERESIS = 1.25
#: samples a filter must have taken before its values are used (a single sample can be an
#: outlier the gate did not catch; a car pulling up needs its brake gain within a second)
MIN_UPDATES = 2


@dataclass(frozen=True)
class LearnedModel:
    """The values a controller and the state estimator predict with: eq. 7, eq. 8 per zone
    (in the file's zone order), dead times and lags [s]."""

    offset_rad: float
    scale: float
    zone_offset_mps2: tuple
    zone_scale_mps2: tuple
    zone_brake_mps2: tuple
    steer_delay_s: float
    long_delay_s: float
    steer_lag_s: float
    long_lag_s: float


def file_timing(params: Params) -> tuple[float, float, float, float]:
    """(steering dead time, longitudinal dead time, steering lag, longitudinal lag) [s] of a
    parameter file, as the controller reads them."""
    ext, _st, _lon = plant_extensions(params)
    assert params.steering is not None
    return (
        float(params.steering.dead_time_s or 0.0),
        float(params.longitudinal_dead_time_s or 0.0),
        ext.lag_steer_s if ext is not None else 0.0,
        ext.lag_long_s if ext is not None else 0.0,
    )


class ModelAdapter:
    """The online model estimator of one run (see the module docstring).

    Args:
        params: the parameter file the controller was given (the start and the bounds).
        period_s: the control period [s].
        config: thresholds (:class:`AdaptConfig`).
        inputs: "pedals" (the commands are pedal positions) or "accel_cmd" (the car takes an
            acceleration request formed from them with the file's eq. 8).
        yaw_rate_noise_radps, accel_noise_mps2: the sensors' white noise (1-sigma); default
            the config's.
    """

    def __init__(
        self,
        params: Params,
        period_s: float,
        config: AdaptConfig | None = None,
        *,
        inputs: str = "pedals",
        yaw_rate_noise_radps: float | None = None,
        accel_noise_mps2: float | None = None,
    ):
        if not params.is_model:
            raise ValueError("the online model estimator needs a complete model")
        c = self.cfg = config or AdaptConfig()
        self.params = params
        st = params.steering
        assert st is not None  # a complete model
        self._eq7_file = (float(st.offset_rad), float(st.scale))  # the straight-running gate
        self._wheelbase_m = float(params.vehicle.wheelbase_m)
        self.period_s = float(period_s)
        veh = params.vehicle
        self.signals = PeriodSignals(c, float(veh.track_rear_m or veh.track_front_m))
        self.steering = SteeringLearner(params, c, yaw_rate_noise_radps or c.yaw_rate_noise_radps)
        self.zones = ZoneLearner(
            params, c, period_s, inputs, accel_noise_mps2 or c.accel_noise_mps2
        )
        self.inputs = inputs
        # the response fits of the two channels (0 steering, 1 longitudinal), every
        # ``_fit_every`` control periods (the fit's period: about TIMING_PERIOD_S)
        self._fit_every = max(int(round(TIMING_PERIOD_S / period_s)), 1)
        self.fit = ResponseFit(
            c, period_s * self._fit_every, (c.timing_steer_step_rad, c.timing_long_step_mps2)
        )
        self._fit_n = 0  # commands summed into the fit's period
        self._fit_periods = 0  # control periods ended in it
        self._fit_cmd = [0.0, 0.0]  # the commands' sums
        self._fit_y = [0.0, 0.0]  # their usable responses' sums, and counts
        self._fit_ny = [0, 0]
        self._cmd2 = [0.0, 0.0]
        self.timing_file = file_timing(params)
        self.timing_used = list(self.timing_file)
        self.timing_est: dict[str, dict | None] = {"steering": None, "longitudinal": None}
        self.zones.use_timing(self.timing_used[1], self.timing_used[3])
        self._v_max = [z.v_max_mps for z in params.zones]
        self._t_prev: float | None = None
        self.t0_s: float | None = None  # time of the first learning step [s]
        self._v_prev = math.nan
        self._sw_prev = math.nan
        self._t_timing = -math.inf
        self._drift_s = 0.0
        self._force_push = False  # hand the model over at the next step (restore)
        self._changed = False  # a learner moved since the last hand-over check
        self._t_push = -math.inf
        self._ab_num = self._ab_den = 0.0  # accelerometer bias: forgotten sums (learn)
        self.events: list[tuple[float, str]] = []
        self._coefs = (
            ("offset_mps2", "scale_mps2", "brake_scale_mps2")
            if inputs == "pedals"
            else ("offset_mps2", "accel_cmd_gain")
        )
        self._plist = self._param_list()
        self.valid = [False] * len(self._plist)
        self.identified = [False] * len(self._plist)
        self._groups = [(self.steering.filter, [0, 1])] + [
            (zf, list(range(2 + zi * len(self._coefs), 2 + (zi + 1) * len(self._coefs))))
            for zi, zf in enumerate(self.zones.filters)
        ]
        self.keys = self._keys()
        self.initial = self._values_now()
        self._pushed_values = self._used_values()
        nz = len(params.zones)
        self._push_tol = (
            [(c.push_offset_rad, 0.0), (0.0, c.push_scale_rel)]
            + [(c.push_zone_offset_mps2, 0.0)] * nz
            + [(0.0, c.push_gain_rel)] * (2 * nz)
            + [(0.5 * c.push_timing_s, 0.0)] * 4
        )
        self.history = History(len(self.keys), c.history_period_s)
        self.cost_s: list = []  # not filled here: the loop times learn() and use_model()

    # ------------------------------------------------------------------ inputs
    def feed(self, m) -> None:
        """A ``models.sim.live_sensors.Measurement`` (or anything with ``kind``, ``t_meas_s``,
        ``values``): CAN wheel speeds, steering angle, yaw rate; IMU yaw rate, acceleration."""
        v = m.values
        if m.kind == "can":
            self.signals.add_can(
                m.t_meas_s,
                v.get("wheel_speeds_mps"),
                v.get("steering_wheel_angle_rad"),
                v.get("yaw_rate_radps"),
            )
        elif m.kind == "imu":
            self.signals.add_imu(m.t_meas_s, v.get("yaw_rate_radps"), v.get("accel_x_mps2"))

    def commanded(
        self,
        t_s: float,
        steering_wheel_angle_rad: float,
        accel_pedal: float,
        brake_pedal: float,
        v_mps: float | None = None,
    ) -> None:
        """The command sent to the actuators at ``t_s`` [s] (held for one period); ``v_mps``
        the speed then (the zone of an acceleration request; default the last one)."""
        v = self._v_prev if v_mps is None else v_mps
        z = self.params.zones[_zone(v, self._v_max)]
        a_cmd = z.offset_mps2 + z.scale_mps2 * accel_pedal - z.brake_scale_mps2 * brake_pedal
        fc = self._fit_cmd
        fc[0] += steering_wheel_angle_rad
        if self.inputs == "pedals":
            self.zones.commanded((accel_pedal, brake_pedal))
            fc[1] += a_cmd - z.offset_mps2
        else:
            self.zones.commanded((a_cmd,))
            fc[1] += a_cmd
        self._fit_n += 1

    # ------------------------------------------------------------------ learning
    def learn(self, t_s: float, v_mps: float, gyro_bias_radps: float = 0.0) -> LearnedModel | None:
        """Learn from the period that ended at ``t_s`` [s] (module docstring); ``v_mps`` and
        ``gyro_bias_radps``: the state estimator's speed [m/s] and gyro bias [rad/s] now.
        Returns the model to hand over when it changed materially, else None."""
        sig = self.signals
        if self.t0_s is None:  # the history starts with the values the run started from
            self.t0_s = t_s
            self.history.add(t_s, [self.initial[k] for k in self.keys])
        t_prev, v_prev = self._t_prev, self._v_prev
        self._t_prev, self._v_prev = t_s, v_mps
        if t_prev is None or not (t_s > t_prev) or not math.isfinite(v_mps):
            sig.clear()
            return None
        dt = t_s - t_prev
        self._drift_s += dt
        v_lo, v_hi = (
            (min(v_prev, v_mps), max(v_prev, v_mps)) if v_prev == v_prev else (v_mps, v_mps)
        )
        v = 0.5 * (v_lo + v_hi)
        suspect = sig.suspect(t_s)
        changed = force = self._force_push
        self._force_push = False
        sw = sig.sum_sw / sig.n_sw if sig.n_sw else math.nan
        dv_dt = (v_mps - v_prev) / dt if v_prev == v_prev else 0.0
        yaw_mean = sig.sum_yaw / sig.n_yaw if sig.n_yaw else math.nan
        straight = self._straight(sw, yaw_mean)
        if sig.n_acc:
            accel = sig.sum_acc / sig.n_acc
            if v_prev == v_prev and straight:  # the accelerometer's bias against the speed
                lam = math.exp(-dt / self.cfg.accel_bias_window_s)
                self._ab_num = lam * self._ab_num + accel * dt - (v_mps - v_prev)
                self._ab_den = lam * self._ab_den + dt
            t0 = self.cfg.accel_bias_prior_s  # the bias's MAP estimate (config)
            accel -= self._ab_num * self._ab_den / (self._ab_den * self._ab_den + t0 * t0)
        else:
            accel = dv_dt
        # eq. 8's sample: the accelerometer while straight, else the speed's change
        n_acc = sig.n_acc if straight else 0
        accel8 = accel if n_acc else dv_dt
        fy, fn = self._fit_y, self._fit_ny
        self.zones.advance()
        if sig.n_yaw and sw == sw and v >= self.cfg.steer_v_min_mps and not suspect:
            yaw = yaw_mean - gyro_bias_radps
            if sig.n_sw >= 2 and sig.t_sw_last > sig.t_sw_first:
                sw_rate = (sig.sw_last - sig.sw_first) / (sig.t_sw_last - sig.t_sw_first)
            else:
                sw_rate = (sw - self._sw_prev) / dt if self._sw_prev == self._sw_prev else 0.0
            st = self.steering
            if st.gate(v, yaw, sw_rate, accel, suspect):
                self._drift_all()
                st.learn(v, yaw, sig.n_yaw, sw)
                changed = True
            if abs(v * yaw) <= self.cfg.steer_lat_accel_max_mps2:
                fy[0] += st.road_wheel_angle(yaw, v)
                fn[0] += 1
        self._sw_prev = sw
        if v_lo >= self.cfg.long_v_min_mps and (sig.n_acc or v_prev == v_prev):
            # the dead-time and lag fit keeps the accelerometer in turns too: its offset and
            # gain are free (controller/adapt/timing.py), so a reading scaled by cos(delta)
            # moves no timing, and the speed's change would add its noise to every period
            fy[1] += accel
            fn[1] += 1
            z = self.zones.zone_of(v_lo, v_hi)
            if z >= 0 and (n_acc or v_prev == v_prev):
                self._drift_all()
                self.zones.learn(z, accel8, n_acc)
                changed = True
        sig.clear()
        self._fit_periods += 1
        if self._fit_periods >= self._fit_every and self._fit_n:
            self._fit_period(t_s)
        if t_s - self._t_timing >= TIMING_EVERY_S:
            self._t_timing = t_s
            self._drift_all()
            self._update_timing()
            changed = True
        self._record(t_s)
        self._changed = self._changed or changed
        if force or (self._changed and t_s - self._t_push >= PUSH_EVERY_S - 1e-9):
            self._t_push, self._changed = t_s, False
            return self._push_if_changed(t_s, force)
        return None

    def _straight(self, sw_rad: float, yaw_rate_radps: float) -> bool:
        """Whether the period's accelerometer reading stands for eq. 8's acceleration: the
        car ran straight (``AdaptConfig.long_imu_delta_max_rad``,
        ``long_imu_centripetal_max_mps2``); a NaN steering angle or yaw rate (none this
        period) does not say it turned."""
        c = self.cfg
        off, scale = self._eq7_file
        if abs(off + scale * sw_rad) > c.long_imu_delta_max_rad:
            return False
        return not yaw_rate_radps * yaw_rate_radps * self._wheelbase_m > (
            c.long_imu_centripetal_max_mps2
        )

    def _fit_period(self, t_s: float) -> None:
        """The response fits' period that ended at ``t_s``: each channel's mean response,
        usable when every control period of it was (a partly usable period teaches no
        timing)."""
        fit, fy, fn, k = self.fit, self._fit_y, self._fit_ny, self._fit_periods
        fc, n = self._fit_cmd, self._fit_n  # the commands that acted over the period
        self._cmd2[0], self._cmd2[1] = fc[0] / n, fc[1] / n
        fit.command(t_s, self._cmd2)
        fc[0] = fc[1] = 0.0
        self._fit_n = self._fit_periods = 0
        fit.advance()
        for ch in (0, 1):
            full = fn[ch] >= k
            fit.weight[ch] = 1.0 if full else 0.0
            fit.y[ch] = fy[ch] / k if full else 0.0
            fy[ch], fn[ch] = 0.0, 0
        fit.add(t_s)

    def _drift_all(self) -> None:
        """Apply the drift of the time since the last call to every filter (lazily: the
        variances only matter when a filter is updated or read)."""
        if self._drift_s > 0.0:
            self.steering.filter.drift(self._drift_s)
            self.zones.drift(self._drift_s)
            self._drift_s = 0.0

    def _update_timing(self) -> None:
        """Evaluate the dead-time and lag fits; use a valid one whose 95 % set excludes the
        file's values."""
        for k, (ch, (i_d, i_l)) in enumerate((("steering", (0, 2)), ("longitudinal", (1, 3)))):
            est = self.fit.estimate(k)
            self.timing_est[ch] = est
            d0, l0 = self.timing_file[i_d], self.timing_file[i_l]
            if (
                est is not None
                and est["valid"]
                and not (
                    est["delay_ci95_s"][0] <= d0 <= est["delay_ci95_s"][1]
                    and est["lag_ci95_s"][0] <= l0 <= est["lag_ci95_s"][1]
                )
            ):
                d, lag = est["delay_s"], est["lag_s"]
            else:
                d, lag = d0, l0
            if (self.timing_used[i_d], self.timing_used[i_l]) != (d, lag):
                self.timing_used[i_d], self.timing_used[i_l] = d, lag
                if ch == "longitudinal":
                    self.zones.use_timing(d, lag)

    # ------------------------------------------------------------------ the model
    def _param_list(self) -> list:
        """(KEY, filter, index, threshold, relative) of every filter parameter, in key order."""
        c = self.cfg
        f = self.steering.filter
        out = [
            (KEY_STEER_OFFSET, f, OFFSET, c.valid_steer_offset_ci_rad, False),
            (KEY_STEER_SCALE, f, SCALE, c.valid_steer_scale_rel_ci, True),
        ]
        for name, zf in zip(self.zones.names, self.zones.filters):
            for i, coef in enumerate(self._coefs):
                thr = c.valid_offset_ci_mps2 if i == 0 else c.valid_gain_rel_ci
                out.append((zone_key(name, coef), zf, i, thr, i > 0))
        return out

    def _check_validity(self) -> None:
        """Each filter parameter's ``identified`` (its 95 % half-width within
        identification's threshold; once identified, within ``VALID_HYSTERESIS`` times it) and
        ``valid``: its filter (the steering map, a zone) is in use, which it is once data has
        taught it ``MIN_UPDATES`` times, while no parameter of it is at its bound and its last
        samples have not disagreed with it (the filter is not widening). A filter's parameters
        are used together: a zone's offset and gain fitted at one pedal position predict that
        position only as a pair."""
        ident, valid = self.identified, self.valid
        for j, (_k, f, i, thr, rel) in enumerate(self._plist):
            v = f.theta[i]
            lim = thr * abs(v) if rel else thr
            if ident[j]:
                lim *= VALID_HYSTERESIS
            ident[j] = (f.updates[i] > 0 or f.restored) and 3.8416 * f.P[i][i] <= lim * lim
        for f, js in self._groups:
            ok = (
                (f.restored or max(f.updates) >= MIN_UPDATES)
                and not any(f.at_bound)
                and f.rejects_run < f.widen_after // 2
            )
            for j in js:
                valid[j] = ok

    def _why_not(self, j: int) -> str:
        """Why parameter ``j`` of ``_plist`` is not used, or not identified ("" when it is
        both)."""
        _k, f, i, thr, rel = self._plist[j]
        if any(f.at_bound):
            return "at its bound (a change this large is a broken sensor or another car)"
        if max(f.updates) < MIN_UPDATES and not f.restored:
            return "no data has exercised it"
        if f.rejects_run >= f.widen_after // 2:
            return "the last samples disagree with it"
        if not self.identified[j]:
            lim = thr * abs(f.theta[i]) if rel else thr
            return (
                f"not identified: its 95 % interval +-{1.96 * f.sigma(i):.4g} is wider "
                f"than {lim:.4g}"
            )
        return ""

    def _used_values(self) -> list:
        """The values in use (``valid`` current): [offset, scale, zone offsets..., zone
        scales..., zone brake scales..., steering delay, longitudinal delay, steering lag,
        longitudinal lag]."""
        valid, zl = self.valid, self.zones
        st = self.steering
        th = st.filter.theta
        out = [
            th[OFFSET] if valid[0] else st.file[OFFSET],
            th[SCALE] if valid[1] else st.file[SCALE],
        ]
        nz, nc = len(zl.names), len(self._coefs)
        zo, zs, zb = [0.0] * nz, [0.0] * nz, [0.0] * nz
        for zi, zf in enumerate(zl.filters):
            j0 = 2 + zi * nc
            z = zl.zones[zi]
            if nc == 3:
                t = zf.theta
                zo[zi] = t[0] if valid[j0] else z.offset_mps2
                zs[zi] = t[1] if valid[j0 + 1] else z.scale_mps2
                zb[zi] = t[2] if valid[j0 + 2] else z.brake_scale_mps2
            else:  # offset and command gain act together on all three
                zo[zi], zs[zi], zb[zi] = zl.effective(
                    zi, (zf.theta[0] if valid[j0] else 0.0, zf.theta[1] if valid[j0 + 1] else 1.0)
                )
        return out + zo + zs + zb + list(self.timing_used)

    def _model_of(self, u: list) -> LearnedModel:
        nz = len(self.zones.names)
        return LearnedModel(
            u[0],
            u[1],
            tuple(u[2 : 2 + nz]),
            tuple(u[2 + nz : 2 + 2 * nz]),
            tuple(u[2 + 2 * nz : 2 + 3 * nz]),
            *u[2 + 3 * nz :],
        )

    def model(self) -> LearnedModel:
        """The model in use now: each learned value while valid, the file's otherwise."""
        return self._model_of(self._used_values())

    def _push_if_changed(self, t_s: float, force: bool = False) -> LearnedModel | None:
        """The model in use if a value moved by more than its immaterial amount since the
        last hand-over (and the events of parameters that stopped being valid)."""
        prev = list(self.valid)
        self._check_validity()
        for j, was in enumerate(prev):
            if was and not self.valid[j]:
                self.events.append(
                    (t_s, f"{self._plist[j][0]}: {self._why_not(j)}; the file's value is used")
                )
        u = self._used_values()
        p, tol = self._pushed_values, self._push_tol
        for a, b, (ta, tr) in zip(u, p, tol):
            if abs(a - b) > ta + tr * abs(b) or force:
                self._pushed_values = u
                return self._model_of(u)
        return None

    # ------------------------------------------------------------------ results
    def _keys(self) -> list[str]:
        return [k for k, *_ in self._plist] + [
            KEY_STEER_DELAY,
            KEY_STEER_LAG,
            KEY_LONG_DELAY,
            KEY_LONG_LAG,
        ]

    def _values_now(self) -> dict:
        """KEY -> (estimate, 1-sigma) now (the timing's sigma from its 95 % set)."""
        out = {k: (f.theta[i], f.sigma(i)) for k, f, i, _t, _r in self._plist}
        for ch, (kd, kl), (i_d, i_l) in (
            ("steering", (KEY_STEER_DELAY, KEY_STEER_LAG), (0, 2)),
            ("longitudinal", (KEY_LONG_DELAY, KEY_LONG_LAG), (1, 3)),
        ):
            est = self.timing_est[ch]
            if est is None:
                out[kd] = (self.timing_file[i_d], math.nan)
                out[kl] = (self.timing_file[i_l], math.nan)
            else:
                out[kd] = (est["delay_s"], (est["delay_ci95_s"][1] - est["delay_ci95_s"][0]) / 3.92)
                out[kl] = (est["lag_s"], (est["lag_ci95_s"][1] - est["lag_ci95_s"][0]) / 3.92)
        return out

    def _record(self, t_s: float) -> None:
        h = self.history
        if t_s - h.t_last < h.period_s - 1e-9:
            return
        self._drift_all()
        vals = self._values_now()
        h.add(t_s, [vals[k] for k in self.keys])

    def report(self, t0_s: float | None = None) -> dict:
        """The run JSON's ``adaptation`` (``controller.adapt.report.adaptation_report``)."""
        return adaptation_report(self, t0_s)

    def summary(self) -> dict:
        """Counts for ``details.adaptation`` (``controller.adapt.report.adaptation_counts``)."""
        return adaptation_counts(self)


def _zone(v: float, v_max: list) -> int:
    if not v == v:
        return 0
    for i, hi in enumerate(v_max):
        if v <= hi:
            return i
    return len(v_max) - 1
