"""Benchmark recordings for the diagnosis: one per catalogue effect, a clean one, and one with
physics outside the catalogue, from the ground-truth simulator (``models.sim``) at realistic
sizes (the report's six experiments in a row, about 10 minutes) and fixed seeds.

``CASES`` maps a case name to (expected catalogue id or None, subsystem, effects, truth
parameter name and value as the diagnosis reports it). :func:`make_case` returns the
recording (the experiments joined by ``models.identify.pipeline.concat_recordings`` with
2-s gaps) and the truth.

The hilly road (``models.sim.effects_extra.HillyRoad``) is applied here to the INS altitude and
pitch, which the simulator only knows for a constant grade: the altitude is integrated from the
truth's speed and the profile's grade, the pitch gets the grade added.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hmpc.models.identify.pipeline import concat_recordings
from hmpc.models.logs.recording import Recording
from hmpc.models.sim import effects as fx
from hmpc.models.sim import effects_extra as fx2
from hmpc.models.sim.simulator import random_params, run_experiment

LON_EXPERIMENTS = ("ramps", "ramp_sequence", "open_loop", "ramps", "ramp_sequence", "open_loop")
STEER_EXPERIMENTS = ("arcs", "figure8", "circles", "arcs", "figure8", "circles")
ALL_EXPERIMENTS = ("arcs", "ramps", "figure8", "ramp_sequence", "circles", "open_loop")

#: case -> (expected id, subsystem, effect factory, (parameter, truth value), experiments)
CASES: dict[str, tuple[Any, ...]] = {
    "actuator_delay_steering": (
        "actuator_delay",
        "steering",
        lambda: [fx.SteeringDeadTime(0.25)],
        ("delay_s", 0.25),
        STEER_EXPERIMENTS,
    ),
    "actuator_delay_longitudinal": (
        "actuator_delay",
        "longitudinal",
        lambda: [fx.PedalDeadTime(0.4)],
        ("delay_s", 0.4),
        LON_EXPERIMENTS,
    ),
    "actuator_lag": (
        "actuator_lag",
        "steering",
        lambda: [fx.SteeringLag(0.3)],
        ("tau_s", 0.3),
        STEER_EXPERIMENTS,
    ),
    "steering_nonlinearity": (
        "steering_nonlinearity",
        "steering",
        lambda: [fx.SteeringCubic(0.004)],
        ("cubic_per_rad2", 0.004),
        STEER_EXPERIMENTS,
    ),
    "understeer": (
        "understeer",
        "steering",
        lambda: [fx.Understeer(0.004)],
        ("gradient_rad_per_mps2", 0.004),
        STEER_EXPERIMENTS,
    ),
    "aero_drag": (
        "aero_drag",
        "longitudinal",
        lambda: [fx.AeroDrag(1.5e-3)],
        ("coeff_per_m", 1.5e-3),
        LON_EXPERIMENTS,
    ),
    "road_grade": (
        "road_grade",
        "longitudinal",
        lambda: [fx2.HillyRoad(0.05, 150.0)],
        ("gain", 1.0),
        LON_EXPERIMENTS,
    ),
    "idle_creep": (
        "idle_creep",
        "longitudinal",
        lambda: [fx2.IdleCreep(0.6, 2.0)],
        ("accel_mps2", 0.6),
        LON_EXPERIMENTS,
    ),
    "wheel_radius_error": (
        "wheel_radius_error",
        "longitudinal",
        lambda: [fx.WheelRadiusError(1.03)],
        ("scale", 1.03),
        ALL_EXPERIMENTS,
    ),
    "sensor_time_offset": (
        "sensor_time_offset",
        "longitudinal",
        lambda: [fx.ClockOffset(0.3)],
        ("offset_s", 0.3),
        ALL_EXPERIMENTS,
    ),
    "clean": (None, None, lambda: [], None, ALL_EXPERIMENTS),
    "mass_change": (
        None,
        "longitudinal",
        lambda: [fx2.MassChange(0.0, 0.7)],
        None,
        LON_EXPERIMENTS,
    ),
}


def _hilly(run, eff: fx2.HillyRoad) -> None:
    tr = run.truth
    v = tr["v_mps"]
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * tr.dt_s)])
    g = eff.grade_at(s)
    z = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * tr.dt_s * np.sin(g[:-1]))])
    ch = run.recording.channels
    ch["z"] = ch["z"] + z[run.grid_index]
    ch["pitch"] = ch["pitch"] + g[run.grid_index]


def make_case(case: str, seed: int = 0, params_seed: int | None = None) -> tuple[Recording, dict]:
    """(recording, truth) of benchmark ``case`` (a key of ``CASES``), seeded.

    The mass change is the second half of the experiments driven with 0.7 times the pedal
    authority; its truth holds ``change_t_s``, the recording time where it starts.
    """
    expect, subsystem, make_effects, param, exps = CASES[case]
    truth = random_params(seed if params_seed is None else params_seed)
    recs = []
    for i, name in enumerate(exps):
        effects = make_effects()
        if case == "mass_change" and i < len(exps) // 2:
            effects = []
        run = run_experiment(name, truth, seed=seed * 100 + i, effects=effects)
        for e in effects:
            if isinstance(e, fx2.HillyRoad):
                _hilly(run, e)
        recs.append(run.recording)
    rec = concat_recordings(recs)
    rec.meta["path"] = f"<benchmark {case} seed {seed}>"
    info: dict[str, Any] = {
        "case": case,
        "effect": expect,
        "subsystem": subsystem,
        "params": truth,
        "parameter": param,
        "seed": seed,
    }
    if case == "mass_change":
        n_first = sum(len(r) for r in recs[: len(recs) // 2])
        info["change_t_s"] = float(rec.time[n_first + int(2.0 * recs[0].rate_hz) - 1])
    return rec, info
