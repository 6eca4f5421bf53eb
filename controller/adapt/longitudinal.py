"""Eq. 8 per zone learned on line (:class:`ZoneLearner`).

Each control period gives one sample: the period's mean measured acceleration against the
commands that acted over it, through the actuator dead time and lag in use
(:mod:`~hmpc.controller.adapt.timing`). Two kinds of car:

- **pedal-driven** (``inputs="pedals"``): ``a = offset_z + scale_z ap - brake_scale_z bp``,
  three parameters per zone;
- **driven by an acceleration command** (``inputs="accel_cmd"``, e.g. a Toyota's ACC
  request, which the drive loop forms from the pedal plan with the file's eq. 8):
  ``a = offset_z + gain_z a_cmd``, two per zone. The model the controller predicts with is
  then eq. 8 of the file seen through the learned command response:
  ``offset_z + gain_z offset_file``, ``gain_z scale_file``, ``gain_z brake_scale_file``.

What a sample may teach (identification's reasoning, ``models.identify.longitudinal``): only
the zone the car is in, and only away from its boundaries (``long_boundary_margin_mps``, the
plant's zone hysteresis), above ``long_v_min_mps`` (a held car does not follow eq. 8); a pedal's
gain only while that pedal is pressed (``long_pressed``; the command gain while the command
exceeds ``long_cmd_min_mps2``): a coefficient whose input the data does not exercise holds. A
zone the car is not in holds all its values.
"""

from __future__ import annotations

from hmpc.models.params import Params
from hmpc.models.zones import zone_of_speed

from hmpc.controller.adapt.config import AdaptConfig
from hmpc.controller.adapt.paramfilter import ParamFilter
from hmpc.controller.adapt.timing import CommandHistory, lag_coefficients, lagged_mean

#: the two kinds of longitudinal input
INPUTS = ("pedals", "accel_cmd")
_S_PER_RTH = 60.0  # sqrt(3600 s)


class ZoneLearner:
    """One parameter filter per zone and their gates (see the module docstring).

    Args:
        params: the parameter file it starts from (the zones).
        config: gates, priors, bounds.
        period_s: the control period [s] (one command per period).
        inputs: "pedals" or "accel_cmd".
        accel_noise_mps2: the accelerometer's white noise (1-sigma) [m/s^2].
    """

    def __init__(
        self,
        params: Params,
        config: AdaptConfig,
        period_s: float,
        inputs: str,
        accel_noise_mps2: float,
    ):
        if inputs not in INPUTS:
            raise ValueError(f"inputs must be one of {INPUTS}, got {inputs!r}")
        c = config
        self.cfg, self.inputs, self.period_s = c, inputs, float(period_s)
        self.zones = params.zones
        self.names = [z.name for z in params.zones]
        self._v_min = [z.v_min_mps for z in params.zones]
        self._v_max = [z.v_max_mps for z in params.zones]
        self.filters = [self._filter(z) for z in params.zones]
        self._acc_var = float(accel_noise_mps2) ** 2
        self._dv_var = (c.long_speed_change_noise_mps / self.period_s) ** 2
        n = 3 if inputs == "pedals" else 2
        self._h = [1.0] + [0.0] * (n - 1)
        self._free = [True] + [False] * (n - 1)
        cap = int(round(c.timing_max_s / period_s)) + 3
        self._hist = [CommandHistory(cap) for _ in range(n - 1)]
        self._e = [0.0] * (n - 1)
        self._mean = [0.0] * (n - 1)
        self.use_timing(0.0, 0.0)
        self.samples = {"used": 0, "gated": 0}

    def _filter(self, z) -> ParamFilter:
        c = self.cfg
        so, sg = c.long_offset_prior_mps2, c.long_gain_prior_rel
        wo, wg = c.long_offset_walk_mps2_rth / _S_PER_RTH, c.long_gain_walk_rel_rth / _S_PER_RTH
        bo, bg = c.long_offset_bound_mps2, c.long_gain_bound_rel
        if self.inputs == "pedals":
            th = [z.offset_mps2, z.scale_mps2, z.brake_scale_mps2]
            return ParamFilter(
                th,
                [so, sg * th[1], sg * th[2]],
                [wo, wg * th[1], wg * th[2]],
                [th[0] - bo, th[1] * (1 - bg), th[2] * (1 - bg)],
                [th[0] + bo, th[1] * (1 + bg), th[2] * (1 + bg)],
                gate_chi2=c.gate_chi2,
                widen_after=c.reject_widen_after,
            )
        return ParamFilter(
            [0.0, 1.0],
            [so, sg],
            [wo, wg],
            [-bo, 1 - bg],
            [bo, 1 + bg],
            gate_chi2=c.gate_chi2,
            widen_after=c.reject_widen_after,
        )

    def use_timing(self, delay_s: float, lag_s: float) -> None:
        """The dead time and lag [s] the commands act through (the ones in use)."""
        m, f, a1, b1, a2, b2 = lag_coefficients([delay_s], [lag_s], self.period_s)
        self._timing = (
            int(m[0]),
            float(f[0]),
            float(a1[0]),
            float(b1[0]),
            float(a2[0]),
            float(b2[0]),
        )

    def commanded(self, inputs) -> None:
        """The commands issued now: (accel pedal, brake pedal) or (acceleration command,)."""
        for hist, u in zip(self._hist, inputs):
            if hist.count == 0:
                hist.ring[:] = u
            hist.push(float(u))

    def advance(self) -> None:
        """The commands' means over the period that just ended, through the timing in use."""
        m, f, a1, b1, a2, b2 = self._timing
        for i, hist in enumerate(self._hist):
            if hist.count == 0:
                continue
            self._mean[i], self._e[i] = lagged_mean(
                self._e[i], hist.value(m + 1), hist.value(m), f, a1, b1, a2, b2
            )

    def zone_of(self, v_lo_mps: float, v_hi_mps: float) -> int:
        """The zone a period with speeds in [v_lo, v_hi] [m/s] may teach, or -1: too slow,
        or near a zone boundary (module docstring)."""
        c = self.cfg
        if v_lo_mps < c.long_v_min_mps:
            return -1
        z = zone_of_speed(v_lo_mps, self._v_max, clamp=True)
        margin = c.long_boundary_margin_mps
        if (z > 0 and v_lo_mps - self._v_min[z] < margin) or (
            z < len(self._v_max) - 1 and self._v_max[z] - v_hi_mps < margin
        ):
            return -1
        return z

    def drift(self, dt_s: float) -> None:
        for f in self.filters:
            f.drift(dt_s)

    def learn(self, zone: int, accel_mps2: float, n_acc: int) -> bool:
        """One sample of ``zone`` (from :meth:`zone_of`): the period's mean acceleration
        [m/s^2] over ``n_acc`` accelerometer samples, or with ``n_acc`` 0 the speed's change
        over the period (``AdaptConfig.long_speed_change_noise_mps``), against the commands'
        means of :meth:`advance`."""
        c = self.cfg
        if abs(accel_mps2) > c.long_accel_abs_max_mps2:
            self.samples["gated"] += 1
            return False
        h, free, u = self._h, self._free, self._mean
        if self.inputs == "pedals":
            h[1], h[2] = u[0], -u[1]
            free[1], free[2] = u[0] > c.long_pressed, u[1] > c.long_pressed
        else:
            h[1] = u[0]
            free[1] = abs(u[0]) > c.long_cmd_min_mps2
        r = (self._acc_var / n_acc if n_acc else self._dv_var) + c.long_noise_floor_mps2**2
        ok = self.filters[zone].update(h, accel_mps2, r, free)
        self.samples["used" if ok else "gated"] += 1
        return ok

    def effective(self, zone: int, theta) -> tuple[float, float, float]:
        """(offset, scale, brake scale) of eq. 8 the controller predicts with, from the
        parameters ``theta`` of ``zone``'s filter (module docstring)."""
        if self.inputs == "pedals":
            return float(theta[0]), float(theta[1]), float(theta[2])
        z = self.zones[zone]
        g = float(theta[1])
        return (float(theta[0]) + g * z.offset_mps2, g * z.scale_mps2, g * z.brake_scale_mps2)
