"""Delay and lag compensation of the MPC: the actuators' dead times and first-order lags,
predicted through the commands already issued.

Every step the QP starts where the car will be when this step's command takes effect: with
dead times d_s (steering, ``steering.dead_time_s``) and d_l (pedals,
``longitudinal.dead_time_s``) the state is predicted to t + min(d_s, d_l) on the plant with
the commands in flight, and the channel with the longer dead time has its first QP stages
fixed to its in-flight commands (:class:`~hmpc.controller.horizon.InFlight`). With an
``actuator_lag`` in the model's extensions, the lags' outputs are simulated from the issued
commands (exactly, :func:`_lag_through`), the QP plans the lags' outputs and the command is
the lag's inverse (``lag_method``).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant, first_order_lag

from hmpc.controller.horizon import InFlight
from hmpc.controller.limits import Command

#: longest sub-step of the prediction through the dead time [s]
PREDICTION_STEP_S = 0.05
#: commands kept for the prediction (at 10 Hz: 25.6 s, far beyond any dead time)
HISTORY_COMMANDS = 256


def _lag_through(
    e: float, t0_s: float, t1_s: float, times_s: list, values: list, tau_s: float
) -> float:
    """A first-order lag's output at ``t1_s`` from ``e`` at ``t0_s`` [s], its input
    piecewise constant: ``values[i]`` from ``times_s[i]`` on (before the first: ``values[0]``);
    exact (models.plant.first_order_lag per piece)."""
    i = bisect.bisect_right(times_s, t0_s) - 1
    t = t0_s
    while t < t1_s - 1e-12:
        tn = min(times_s[i + 1] if i + 1 < len(times_s) else math.inf, t1_s)
        e = first_order_lag(e, values[max(i, 0)], tn - t, tau_s)
        t, i = tn, i + 1
    return e


@dataclass
class _LagState:
    """The actuator lags' outputs (steering-wheel angle, accel, brake pedal) at ``t_s``, as
    the MPC simulates them from the commands it issued (``history``: a reset starts anew)."""

    t_s: float
    e: list
    history: object


class DelayCompensation:
    """The commands issued (``history``: (t_issue_s, Command)), the inputs in flight at the
    start of the horizon (``fixed``, written by :meth:`predict`) and the actuator lags'
    simulated outputs.

    Args:
        params: the model (its dead times).
        plant: the prediction model (its ``ext`` holds the actuator lags, if any).
        dt_s: the QP's stage length [s].
        n_stages: the number of stages.
    """

    #: how an ``actuator_lag`` of the model is handled (chosen by evidence, see
    #: tools/bench_diagnose.py and the drive tests): "inverse" (the lag simulated in the
    #: prediction through the commands in flight, the QP plans the lag's output and the
    #: command is u + tau du/dt of the plan), "stage" (the same prediction, the command
    #: brings the lag's output to the plan's next stage in one stage), "delay" (the lag
    #: taken as a dead time of tau), "none" (ignored)
    lag_method = "inverse"

    def __init__(self, params: Params, plant: HybridPlant, dt_s: float, n_stages: int):
        assert params.steering is not None
        self.dead_time_steer_s = float(params.steering.dead_time_s or 0.0)
        self.dead_time_long_s = float(params.longitudinal_dead_time_s or 0.0)
        ext = plant.ext
        #: actuator_lag time constants [s] (steering, pedals): see :meth:`command`
        self.lag_s = (0.0, 0.0) if ext is None else (ext.lag_steer_s, ext.lag_long_s)
        self.dt, self.N = dt_s, n_stages
        #: lag outputs (sw, ap, bp) where this step's command starts to act
        self.lag_act: np.ndarray | None = None
        self._lag: _LagState | None = None  # the simulated lag states, set on the first step
        self.reset()

    def reset(self) -> None:
        """Forget the commands issued (a new run)."""
        self.history: deque = deque(maxlen=HISTORY_COMMANDS)  # (t_issue_s, Command)
        self.fixed = InFlight()  # inputs in flight at the start of the horizon

    def predict(
        self,
        x: np.ndarray,
        t_s: float,
        zone: int | None,
        last_cmd: Command | None,
        plant: HybridPlant,
    ) -> tuple[np.ndarray, float]:
        """Predict the measured state ``x`` at ``t_s`` through the inputs in flight, on
        ``plant`` from ``zone`` (the zone of the last step); ``last_cmd``: the last command
        issued (None: none yet).

        With dead times d_s (steering) and d_l (pedals), the QP starts at t + d0,
        d0 = min(d_s, d_l): the state is predicted to then with the commands already issued
        (both channels are known up to t + d0). The channel with the longer dead time has
        its first round((d_c - d0) / dt) QP stages fixed to its in-flight commands
        (``fixed``); its command now is the QP input at the stage where it will act.
        Returns (state at t + d0, d0). With an actuator lag, :meth:`_predict_through_lag`.
        """
        if self.lag_s != (0.0, 0.0) and self.lag_method in ("inverse", "stage"):
            return self._predict_through_lag(x, t_s, zone, last_cmd, plant)
        ds, dl = self.dead_time_steer_s, self.dead_time_long_s
        d0 = min(ds, dl)
        hist = list(self.history)
        last = last_cmd or Command(0.0, 0.0, 0.0)

        def issued_at(tq: float) -> Command:
            cmd = None
            for ti, c in hist:
                if ti <= tq + 1e-9:
                    cmd = c
                else:
                    break
            return cmd if cmd is not None else (hist[0][1] if hist else last)

        dt = self.dt
        k_s = int(round((ds - d0) / dt))
        k_l = int(round((dl - d0) / dt))
        t0 = t_s + d0
        steer = np.array([issued_at(t0 + k * dt - ds).steering_wheel_angle_rad for k in range(k_s)])
        ped = np.array(
            [
                [issued_at(t0 + k * dt - dl).accel_pedal, issued_at(t0 + k * dt - dl).brake_pedal]
                for k in range(k_l)
            ]
        )
        self.fixed = InFlight(k_s, steer, k_l, ped.reshape(k_l, 2))
        if d0 <= 0:
            return x, 0.0
        n_sub = max(int(math.ceil(d0 / PREDICTION_STEP_S)), 1)
        h = d0 / n_sub
        s = x.copy()
        for j in range(n_sub):
            tau = t_s + (j + 0.5) * h
            cs, cl = issued_at(tau - ds), issued_at(tau - dl)
            u = np.array([cs.steering_wheel_angle_rad, cl.accel_pedal, cl.brake_pedal])
            r = plant.step(s, u, h, zone)
            s, zone = r.state, r.zone
        return s, d0

    def use_timing(
        self,
        dead_time_steer_s: float,
        dead_time_long_s: float,
        lag_steer_s: float,
        lag_long_s: float,
    ) -> None:
        """New dead times and lags [s] (new model values), with ``lag_method`` applied as at
        the start (a "delay" method adds the lags to the dead times)."""
        self.lag_s = (float(lag_steer_s), float(lag_long_s))
        self.dead_time_steer_s = float(dead_time_steer_s)
        self.dead_time_long_s = float(dead_time_long_s)
        if self.lag_method == "delay":
            self.dead_time_steer_s += self.lag_s[0]
            self.dead_time_long_s += self.lag_s[1]

    def use_lag_method(self, method: str) -> None:
        """Choose how an ``actuator_lag`` is handled (``lag_method``) before the first step."""
        if method not in ("inverse", "stage", "delay", "none"):
            raise ValueError(f"unknown lag method {method!r}")
        if self.lag_method == "delay":
            self.dead_time_steer_s -= self.lag_s[0]
            self.dead_time_long_s -= self.lag_s[1]
        self.lag_method = method
        if method == "delay":
            self.dead_time_steer_s += self.lag_s[0]
            self.dead_time_long_s += self.lag_s[1]

    def _lag_outputs(self, t_s: float, t_query: np.ndarray, last_cmd: Command | None) -> np.ndarray:
        """The lags' outputs (sw [rad], accel, brake pedal) at the ascending times
        ``t_query`` >= ``t_s`` [s], (n, 3): the issued commands through the dead times and
        the first-order lags (models.plant.first_order_lag), from the state kept at the
        last step (advanced to ``t_s`` here: every command acting until then is issued)."""
        hist = list(self.history)
        if not hist:
            c = last_cmd or Command(0.0, 0.0, 0.0)
            return np.tile(
                [c.steering_wheel_angle_rad, c.accel_pedal, c.brake_pedal], (len(t_query), 1)
            )
        taus = (self.lag_s[0], self.lag_s[1], self.lag_s[1])
        dts = (self.dead_time_steer_s, self.dead_time_long_s, self.dead_time_long_s)
        vals = [
            [c.steering_wheel_angle_rad for _, c in hist],
            [c.accel_pedal for _, c in hist],
            [c.brake_pedal for _, c in hist],
        ]
        times = [[ti + d for ti, _ in hist] for d in dts]
        st = self._lag
        if st is None or st.history is not self.history:  # a new run: at rest on the first
            st = self._lag = _LagState(hist[0][0], [v[0] for v in vals], self.history)
        if t_s > st.t_s:
            st.e = [
                _lag_through(st.e[c], st.t_s, t_s, times[c], vals[c], taus[c]) for c in range(3)
            ]
            st.t_s = t_s
        out = np.empty((len(t_query), 3))
        e, t = list(st.e), t_s
        for k, tq in enumerate(t_query):
            e = [_lag_through(e[c], t, tq, times[c], vals[c], taus[c]) for c in range(3)]
            t = max(t, float(tq))
            out[k] = e
        return out

    def _predict_through_lag(
        self,
        x: np.ndarray,
        t_s: float,
        zone: int | None,
        last_cmd: Command | None,
        plant: HybridPlant,
    ) -> tuple[np.ndarray, float]:
        """:meth:`predict` with the lags' outputs as the plant's inputs: the state at
        t + d0, the in-flight stages fixed to the lags' outputs at their middles, and
        ``lag_act``, the outputs where this step's command starts to act (t + d of its
        channel), for :meth:`command`."""
        ds, dl = self.dead_time_steer_s, self.dead_time_long_s
        d0, dt = min(ds, dl), self.dt
        k_s, k_l = int(round((ds - d0) / dt)), int(round((dl - d0) / dt))
        n_sub = max(int(math.ceil(d0 / PREDICTION_STEP_S)), 1) if d0 > 0 else 0
        h = d0 / n_sub if n_sub else 0.0
        t_sub = t_s + (np.arange(n_sub) + 0.5) * h
        t_fix = t_s + d0 + (np.arange(max(k_s, k_l)) + 0.5) * dt
        t_act = np.array([t_s + ds, t_s + dl])
        tq = np.concatenate([t_sub, t_fix, t_act])
        order = np.argsort(tq, kind="stable")
        e = np.empty((len(tq), 3))
        e[order] = self._lag_outputs(t_s, tq[order], last_cmd)
        e_sub, e_fix, e_act = e[:n_sub], e[n_sub : n_sub + len(t_fix)], e[n_sub + len(t_fix) :]
        self.fixed = InFlight(k_s, e_fix[:k_s, 0].copy(), k_l, e_fix[:k_l, 1:].copy())
        self.lag_act = np.array([e_act[0, 0], e_act[1, 1], e_act[1, 2]])
        s = x.copy()
        for j in range(n_sub):
            r = plant.step(s, e_sub[j], h, zone)
            s, zone = r.state, r.zone
        return s, d0

    def command(self, cmd: Command, U: np.ndarray, zone: int, plant: HybridPlant) -> Command:
        """The command that makes the lags' outputs follow the plan ``U`` (the QP's inputs
        are the lags' outputs): per ``lag_method``, u + tau (u_next - u) / dt ("inverse") or
        the lag's output at the plan's next stage one stage on ("stage"). The pedals are
        inverted as one signal, the pedal force of ``zone`` (scale ap - brake_scale bp): a
        positive result is throttle, a negative one brake, never both."""
        k_s, k_l = self.fixed.steer_stages, self.fixed.pedal_stages
        (ts, tl), e, pl, N = self.lag_s, self.lag_act, plant, self.N
        sw, ap, bp = cmd.steering_wheel_angle_rad, cmd.accel_pedal, cmd.brake_pedal
        if ts > 0 and k_s + 1 < N:
            assert e is not None  # set by _predict_through_lag, which a lag makes predict run
            sw = self._inverse_lag(sw, float(U[k_s + 1, 0]), float(e[0]), ts)
        if tl > 0 and k_l + 1 < N:
            assert e is not None  # set by _predict_through_lag, which a lag makes predict run
            sc, br = max(float(pl.z_scale[zone]), 1e-6), max(float(pl.z_brake[zone]), 1e-6)
            g = self._inverse_lag(
                sc * ap - br * bp,
                sc * float(U[k_l + 1, 1]) - br * float(U[k_l + 1, 2]),
                sc * e[1] - br * e[2],
                tl,
            )
            ap, bp = (min(g / sc, 1.0), 0.0) if g >= 0 else (0.0, min(-g / br, 1.0))
        return Command(float(sw), float(ap), float(bp))

    def _inverse_lag(self, u0: float, u1: float, e: float, tau_s: float) -> float:
        """One channel of :meth:`command`: plan u0 now, u1 a stage on, lag output e."""
        if self.lag_method == "stage":
            return e + (u1 - e) / (1.0 - math.exp(-self.dt / tau_s))
        return u0 + tau_s * (u1 - u0) / self.dt
