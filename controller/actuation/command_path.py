"""The drive loop's command path: from the command the loop holds (steering-wheel angle,
pedals, or the controlled stop's acceleration) to one command frame per role, limited
(``safety.py`` limiter), checked again independently at the encoder (``safety.py`` checks) and
encoded (``builders.py``). A frame the check refuses goes out without its request, and the
reason is counted (``blocked``); a command the limiter changed is counted too (``clips``).

- Toyota (``steer_torque``, ``accel``): an inner angle loop gives the EPS torque
  (STEERING_LKA); the acceleration request (ACC_CONTROL) is the one the loop asks for (eq. 8
  forward of the pedal plan, or the stop's).
- By-wire (``steer_angle``, ``pedals``): the angle and the pedals as they are (BW_STEER_CMD,
  BW_PEDAL_CMD).

Toyota inner angle loop (tuned on the simulator node, whose EPS and steering column are
modelled in ``vehicle_node.py``): torque = k_ff(v) * angle_cmd + kp * e + ki * int(e)
- kd * rate, gains in :class:`InnerAngleLoop`; the integral is frozen while the torque
limiter binds (anti-windup).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import can
import numpy as np

from hmpc.models.params import Params

from hmpc.controller.actuation import builders
from hmpc.controller.actuation.feedback import Feedback
from hmpc.controller.actuation.profiles import ActuationProfile
from hmpc.controller.actuation.safety import (
    AngleCheck,
    AngleLimiter,
    AngleLimits,
    ToyotaLimits,
    ToyotaSteerCheck,
    ToyotaTorqueLimiter,
    accel_ok,
    clip_accel,
    clip_pedals,
    pedals_ok,
)


@dataclass(frozen=True)
class InnerAngleLoop:
    """Gains of the Toyota path's inner angle loop [raw torque units], tuned on the simulator
    node (J 0.04 kg m^2, g 0.005 N m/unit): kp and kd place the loop at about 10 rad/s with
    damping 0.8; the feedforward cancels the self-aligning stiffness (k(v)/g)."""

    kff0: float = 60.0  # units/rad: 0.3 N m/rad / 0.005 N m/unit
    kff2: float = 0.8  # units s^2/(rad m^2): 0.004 / 0.005
    kp: float = 800.0  # units/rad
    ki: float = 400.0  # units/(rad s)
    kd: float = 110.0  # units/(rad/s)


INNER = InnerAngleLoop()


def limit_speed(fb: Feedback, v_meas: float) -> float:
    """The speed [m/s] the speed-scheduled steering limits are taken at: the highest of
    the tick's reading and the freshest wheel speeds (the last look before encoding may
    have decoded newer ones, logged before this frame). The ISO 11270 bounds tighten as
    the speed grows: a stale, lower speed would allow more than the car's state does,
    and the candump audit, which takes the latest speed frame, would count it."""
    vals = [
        v
        for v in (
            v_meas,
            fb.value("speed"),
            0.5 * (fb.value("wheel_speed_fl") + fb.value("wheel_speed_fr")),
        )
        if np.isfinite(v)
    ]
    return max(vals) if vals else 0.0


class CommandPath:
    """The command path's limiters, checks and inner-loop state, kept across ticks, and what it
    counts: commands the limiter changed (``clips``), frames the check refused (``blocked``).

    Args:
        profile: the actuation profile (the by-wire angle check runs at its command's period).
        params: the controller's model (the speed-scheduled angle limits).
        tick_s: the loop's base tick [s] (the inner angle loop's step).
    """

    def __init__(self, profile: ActuationProfile, params: Params, tick_s: float):
        tl = ToyotaLimits()
        al = AngleLimits.from_params(params)
        self.tick_s = tick_s
        self.tl = tl
        self.lim_t = ToyotaTorqueLimiter(tl)
        self.chk_t = ToyotaSteerCheck(tl)
        self.al = al
        self.lim_a = AngleLimiter(al)
        self.chk_a = (
            AngleCheck(al, profile.commands["steer_angle"].period_s)
            if "steer_angle" in profile.commands
            else None
        )
        self.integ = 0.0  # inner angle loop's integral [raw torque units]
        self.rate_f = 0.0  # filtered steering-wheel rate [rad/s]
        self.last_sw: float | None = None  # last measured steering-wheel angle [rad]
        self.prev_pedals: tuple | None = None
        self.last_accel_req = math.nan  # the last acceleration request sent [m/s^2]
        self.clips = {"steer": 0, "long": 0}
        self.blocked: dict[str, int] = {}

    def _block(self, why: str) -> None:
        self.blocked[why] = self.blocked.get(why, 0) + 1

    def steer_torque(
        self,
        fb: Feedback,
        spec,
        cnt: int,
        t: float,
        sw_meas: float,
        v_meas: float,
        sw_cmd: float,
        steer_active: bool,
    ) -> can.Message:
        """Toyota: the inner angle loop's EPS torque, limited and checked (STEERING_LKA)."""
        if np.isfinite(sw_meas):
            if self.last_sw is not None:
                self.rate_f += ((sw_meas - self.last_sw) / self.tick_s - self.rate_f) * 0.3
            self.last_sw = sw_meas
        # panda: controls allowed = cruise on; and no request while the EPS
        # reports a fault (it re-engages from 0 after one)
        allowed = fb.flag("accepts_long")
        steer_ok = allowed and fb.flag("accepts_steer")
        want = 0.0
        if steer_active and np.isfinite(sw_meas):
            vv = v_meas if np.isfinite(v_meas) else 0.0
            e = sw_cmd - sw_meas
            want = (
                (INNER.kff0 + INNER.kff2 * vv * vv) * sw_cmd
                + INNER.kp * e
                + self.integ
                - INNER.kd * self.rate_f
            )
        emin, emax = min(fb.eps), max(fb.eps)
        tq = self.lim_t.clip(want, t, emin, emax, active=steer_active and steer_ok)
        if steer_active and np.isfinite(sw_meas):
            if abs(tq - want) < 1:
                self.integ += INNER.ki * (sw_cmd - sw_meas) * self.tick_s
            else:
                self.clips["steer"] += 1
        else:
            self.integ = 0.0
        req = bool(steer_active and steer_ok)
        self.chk_t.meas.clear()  # the check's EPS samples: the decoded ones
        self.chk_t.meas.extend(fb.eps)
        why = self.chk_t.check(tq, req, t, allowed)
        if why:
            self._block(why)
            self.lim_t.reset(t)
            tq, req = 0, False
        return builders.steering_lka(spec, tq, req, cnt)

    def accel(self, fb: Feedback, spec, a: float, active: bool) -> can.Message:
        """Toyota: the acceleration request ``a`` [m/s^2] (eq. 8 forward, or the stop's),
        limited and checked (ACC_CONTROL)."""
        tl = self.tl
        allowed = fb.flag("accepts_long")
        a2 = clip_accel(a, tl, active=active and allowed)
        if active and allowed and abs(a2 - a) > 1e-9:
            self.clips["long"] += 1
        why = accel_ok(a2, active and allowed, tl)
        if why:
            self._block(why)
            a2 = tl.accel_inactive_mps2 if not (active and allowed) else -1.0
        self.last_accel_req = a2
        return builders.acc_control(spec, a2)

    def steer_angle(
        self,
        fb: Feedback,
        spec,
        cnt: int,
        sw_meas: float,
        v_meas: float,
        sw_cmd: float,
        steer_active: bool,
    ) -> can.Message:
        """By-wire: the steering-wheel angle command, limited and checked (BW_STEER_CMD)."""
        vv = limit_speed(fb, v_meas)
        ang = sw_cmd if steer_active else (sw_meas if np.isfinite(sw_meas) else 0.0)
        a = self.lim_a.clip(ang, vv, spec.period_s)
        if steer_active and abs(a - ang) > 1e-3:
            self.clips["steer"] += 1
        assert self.chk_a is not None  # the profile has a steer_angle command
        why = self.chk_a.check(a, vv)
        if why:
            self._block(why)
            a = self.chk_a.last if self.chk_a.last is not None else 0.0
        return builders.bw_steer_cmd(spec, a, steer_active, cnt)

    def pedals(
        self, spec, cnt: int, ap_cmd: float, bp_cmd: float, active: bool, dt: float
    ) -> can.Message:
        """By-wire: the pedal positions, rate-limited over ``dt`` [s] and checked (BW_PEDAL_CMD)."""
        ap, bp = (ap_cmd, bp_cmd) if active else (0.0, 0.0)
        ap2, bp2 = clip_pedals(ap, bp, self.prev_pedals, dt, self.al)
        if active and (abs(ap2 - ap) > 1e-3 or abs(bp2 - bp) > 1e-3):
            self.clips["long"] += 1
        why = pedals_ok(ap2, bp2, self.al)
        if why:
            self._block(why)
            ap2, bp2 = 0.0, (self.prev_pedals[1] if self.prev_pedals else 0.0)
        self.prev_pedals = (ap2, bp2)
        return builders.bw_pedal_cmd(spec, ap2, bp2, active, cnt)
