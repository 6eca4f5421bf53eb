"""The truth plant: the hybrid plant of ``models.plant`` (eqs. 1, 7 and 8 with the truth
parameters) with concealed effects (``models.sim.effects``), stepped by the experiments' driver
or by any closed loop that wants hidden physics; and the truth record on the internal grid
(:class:`Truth`) that the sensors (``models.sim.measure``) read.

The truth zone is chosen by speed without hysteresis (``params.hysteresis_mps`` if the file
sets it): zone (v_min, v_max] as in ``docs/conventions.md``, so identification by speed
sees the model that acted. At rest the plant holds the car (no rolling backwards), so samples
at v = 0 do not follow eq. 8.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant, StepResult
from hmpc.models.sim.effect_base import Effect


@dataclass
class Truth:
    """The plant's truth on the internal grid (index k = time k * dt_s); inputs held over a step.

    Arrays: ``t_s``; state at the start of each step ``x_m, y_m, psi_rad, v_mps``; measured
    inputs ``sw_rad, accel_pedal, brake_pedal``; what the plant acted on after effects
    ``sw_eff_rad, accel_pedal_eff, brake_pedal_eff``; ``delta_rad`` (eq. 7 of sw_eff),
    ``yaw_rate_radps`` (eq. 1), ``zone`` (index into params.zones), ``accel_model_mps2``
    (eq. 8 of the effective pedals in that zone), ``accel_extra_mps2`` (effects),
    ``accel_mps2`` (applied, with the standstill clamp), ``grade_rad``, ``z_m``, ``low_gear``.
    """

    dt_s: float
    arrays: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def __len__(self) -> int:
        return len(self.arrays["t_s"])


@dataclass
class TruthStep:
    """One step of :class:`TruthPlant`: the plant's result and what it acted on.

    Attributes:
        result: ``models.plant.StepResult`` (new state, zone, applied acceleration [m/s^2]).
        u_eff: inputs after the effects (steering-wheel angle [rad], accel pedal, brake pedal).
        accel_model_mps2: eq. 8 of ``u_eff`` in the zone used [m/s^2].
        accel_extra_mps2: the effects' extra acceleration [m/s^2].
    """

    result: StepResult
    u_eff: tuple[float, float, float]
    accel_model_mps2: float
    accel_extra_mps2: float


class TruthPlant:
    """The hybrid plant with concealed effects: what the experiments (and any closed loop that
    wants hidden physics) drive. Fixed step ``dt_s`` [s] (the effects' delays count steps).

    The zone is chosen by speed without hysteresis unless ``params.hysteresis_mps`` is set
    (a real car has no zone memory; identification assigns zones by speed).

    Args:
        params: the truth (complete model). effects: ``models.sim.effect_base.Effect`` list
            (reset here).
        dt_s: step [s].
    """

    def __init__(self, params: Params, effects: list[Effect] | None = None, dt_s: float = 0.01):
        self.plant = HybridPlant(params, hysteresis_mps=(params.hysteresis_mps or 0.0))
        self.params = params
        self.dt_s = float(dt_s)
        self.effects = list(effects or [])
        for e in self.effects:
            e.start(self.dt_s, params)
        self.zone: int | None = None
        self._steer = [e for e in self.effects if type(e).steering is not Effect.steering]
        self._pedal = [e for e in self.effects if type(e).pedals is not Effect.pedals]
        self._accel = [
            e for e in self.effects if type(e).accel_extra_mps2 is not Effect.accel_extra_mps2
        ]
        self.grade_rad = float(sum(e.grade_rad() for e in self.effects))

    def step(self, state, u) -> TruthStep:
        """Advance one step from ``state`` (x, y, psi, v) with measured inputs ``u``
        (steering-wheel angle [rad], accel pedal, brake pedal) held over it."""
        sw_e, th_e, br_e = float(u[0]), float(u[1]), float(u[2])
        v = float(state[3])
        for e in self._steer:
            sw_e = e.steering(sw_e, v)
        for e in self._pedal:
            th_e, br_e = e.pedals(th_e, br_e)
        u_e = (sw_e, th_e, br_e)
        a_x = 0.0
        for e in self._accel:
            a_x += e.accel_extra_mps2(state, u_e)
        res = self.plant.step(state, u_e, self.dt_s, self.zone, a_x)
        self.zone = res.zone
        return TruthStep(res, u_e, self.plant.accel(res.zone, th_e, br_e), a_x)
