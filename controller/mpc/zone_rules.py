"""How the MPC keeps the car in its most accurate zone (report VI), and the zone of each stage.

- :func:`preferred_zone`: the zone with the lowest ``nmse_pct`` in the parameter file
  (default the zone holding 2-5 m/s);
- :meth:`ZoneRules.schedule`: the zone per stage along the nominal speeds, with the plant's
  hysteresis;
- :meth:`ZoneRules.speed_band`: the report's two ways to stay in the preferred zone, as soft
  speed bounds of the QP: a **minimum-speed floor** (default: the preferred zone's lower
  bound) that applies while the reference is at or above it and that a stop command or an
  obstacle overrides, and a **zone-transition penalty**: the speed is kept inside the
  current zone's hysteresis band unless the reference leaves the band AND the horizon shows
  no acceleration change around the crossing (controller/modes.py
  ``transition_allowed``). Entering the preferred zone is always allowed.
"""

from __future__ import annotations

import math

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant

from hmpc.controller.horizon import SpeedBand
from hmpc.controller.limits import ActuatorLimits
from hmpc.controller.modes import ModeConfig, transition_allowed
from hmpc.controller.mpc.config import MpcConfig


def preferred_zone(params: Params) -> int:
    """The most accurate zone: lowest ``nmse_pct``; without fit metrics, the zone that
    holds 3.5 m/s (the report's low zone, 2-5 m/s, section VI)."""
    scored = [(z.nmse_pct, i) for i, z in enumerate(params.zones) if z.nmse_pct is not None]
    if scored:
        return min(scored)[1]
    return max(params.zone_for(3.5), 0)


class ZoneRules:
    """The zone schedule and the speed band of a horizon (see the module docstring).

    Args:
        params: the model (the preferred zone and its lower bound).
        config: the MPC's tuning (floor, band and transition rule weights).
        mode_config: the mode logic's tuning (its standstill speed).
        limits: the speed limit (the band's default upper bound).
        plant: the prediction model (its zones and hysteresis).
    """

    def __init__(
        self,
        params: Params,
        config: MpcConfig,
        mode_config: ModeConfig,
        limits: ActuatorLimits,
        plant: HybridPlant,
    ):
        N, dt, c, pl = config.n_stages, config.dt_s, config, plant
        self.config, self.mode_config, self.plant, self.N, self.dt = c, mode_config, pl, N, dt
        self.pref_zone = preferred_zone(params)
        floor = c.min_speed_mps
        #: the minimum-speed floor [m/s] (0: none)
        self.floor_mps = params.zones[self.pref_zone].v_min_mps if floor is None else float(floor)
        # each zone's hysteresis band [m/s] (models.zones.zone_with_hysteresis)
        self._zone_bands = [
            (
                -math.inf if z == 0 else pl.v_min[z] - pl.hysteresis_mps,
                pl.v_max[z] + pl.hysteresis_mps if z < pl.n_zones - 1 else math.inf,
            )
            for z in range(pl.n_zones)
        ]
        self._band_v_hi = np.full(N, limits.speed_max_mps)  # speed_band's defaults
        self._band_w_hi = np.full(N, c.w_speed_max * dt)

    def schedule(self, zone0: int, vb: np.ndarray) -> np.ndarray:
        """Zone per stage along the nominal speeds, with the plant's hysteresis. Most steps
        the nominal stays inside ``zone0``'s hysteresis band: then the schedule is
        ``zone0`` throughout (what the plant's stage-by-stage loop gives, checked at once)."""
        lo, hi = self._zone_bands[zone0]
        v = vb[1 : self.N]
        if ((v >= lo) & (v <= hi)).all():
            return np.full(self.N, zone0, dtype=np.int64)
        out = np.empty(self.N, dtype=np.int64)
        out[0] = zone0
        out[1:] = self.plant.zone_schedule(vb[1 : self.N], zone0)
        return out

    def speed_band(self, zone0: int, v_r: np.ndarray, override: bool) -> SpeedBand:
        """Lower/upper speed targets of stages 1..N and the weights of their slacks, from
        the current zone ``zone0`` and the speed reference ``v_r`` (stages 0..N); with
        ``override`` (a stop command or an obstacle) neither the floor nor the band applies."""
        cfg, pl, N, dt = self.config, self.plant, self.N, self.dt
        vr = v_r[1:]
        v_lo = np.zeros(N)
        # speed >= 0: an exact (L1) penalty while the reference moves; where it asks for
        # standstill the quadratic slack term alone keeps the plan at 0 (the brake may
        # press harder than needed at rest; an L1 kink there only slows the solver down)
        w_lo = np.where(vr > self.mode_config.standstill_speed_mps, cfg.w_standstill * dt, 0.0)
        v_hi = self._band_v_hi.copy()
        w_hi = self._band_w_hi.copy()
        if self.floor_mps > 0 and cfg.w_floor > 0 and not override:
            on = vr >= self.floor_mps
            v_lo = np.where(on, self.floor_mps, v_lo)
            w_lo = np.where(on, cfg.w_floor * dt, w_lo)
        if cfg.w_transition > 0:
            m = cfg.transition_band_margin_mps
            lo = pl.v_min[zone0] - pl.hysteresis_mps + m if zone0 > 0 else 0.0
            hi = pl.v_max[zone0] + pl.hysteresis_mps - m if zone0 < pl.n_zones - 1 else np.inf
            outside = (v_r < lo) | (v_r > hi)
            allowed = True
            if outside.any():
                k = int(outside.argmax())
                target = pl.zone_by_speed(float(v_r[k]))
                # a reference that comes to a standstill is a stop command: it overrides
                # the band like the floor (report VI), whatever the acceleration does
                stopping = float(v_r[k:].min()) <= self.mode_config.standstill_speed_mps
                if target != self.pref_zone and not stopping:
                    a_ref = (v_r[1:] - v_r[:-1]) / dt  # np.diff
                    win = max(int(round(cfg.transition_window_s / dt)), 1)
                    dwell = max(int(round(cfg.transition_dwell_s / dt)), 1)
                    stays = bool(outside[k : min(k + dwell, N + 1)].all())
                    allowed = stays and transition_allowed(
                        a_ref, k, win, cfg.transition_accel_tol_mps2
                    )
            else:
                allowed = False  # no transition demanded: leaving the band is penalised
            if not allowed and not override:
                if lo > 0:
                    use = lo > v_lo
                    v_lo = np.where(use, lo, v_lo)
                    w_lo = np.where(use, cfg.w_transition * dt, w_lo)
                if math.isfinite(hi):
                    use = hi < v_hi
                    v_hi = np.where(use, hi, v_hi)
                    w_hi = np.where(use, cfg.w_transition * dt, w_hi)
        return SpeedBand(v_lo, w_lo, v_hi, w_hi)
