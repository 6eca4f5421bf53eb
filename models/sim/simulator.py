"""hmpc's ground-truth simulator: the report's experiments (section III) on a known plant.

``simulate_experiment(name, params)`` drives the hybrid plant of ``models.plant`` (eqs. 1, 7
and 8 with the parameters you give, the truth) through one of the report's experiments and
returns a complete canonical recording: CAN channels quantised as the RAV4's DBC encodes them
and sent at the real message rates, INS channels with the noise of a survey-grade GNSS/INS
(``models.sim.sensors``). ``meta`` holds the truth (parameters, seed, effects, segments, sensor
biases). Concealed physics (dead times, lags, drag, grade, wheel-radius error, clock offset)
is added with ``effects`` (``models.sim.effects``); the default run has none.

How a run is made:

- The experiment's plan (``models.sim.plans``) gives the speed and steering references, or an
  open-loop pedal programme.
- The plant is stepped at an internal rate of at least 100 Hz that is a whole multiple of the
  output rate (100 Hz for the default 50 Hz).
- A driver (``models.sim.driver``) produces the inputs and steps the truth plant, the hybrid
  plant with the effects (``models.sim.truth_plant``): the truth on the internal grid.
- The sensors (``models.sim.measure``) report the truth on the output grid, at a noise level
  of ``"typical"``, ``"quantised"`` or ``"none"``.
- ENU origin at the start, initial heading drawn from the seed.

Runs are repeatable: the same name, parameters, seed, rate, noise and effects give an identical
recording (numpy ``SeedSequence(seed)`` feeds separate streams for plan, driver, CAN and INS).

``run_experiment`` returns the recording with its truth (:class:`SimRun`), ``coverage`` says
what a run exercised (also in ``meta['coverage']``); ``random_params`` draws a plausible truth.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hmpc.models.errors import InputError, ParamError
from hmpc.models.params import Params, Steering, Vehicle, Zone
from hmpc.models.logs.recording import Recording
from hmpc.models.sim.driver import DriverConfig, drive
from hmpc.models.sim.effect_base import Effect
from hmpc.models.sim.measure import NOISE_LEVELS, measure
from hmpc.models.sim.plans import EXPERIMENTS, PLANNERS
from hmpc.models.sim.truth_plant import Truth

#: default geometry for random_params: the report's values (params/report_2008.yaml).
DEFAULT_VEHICLE: dict[str, Any] = {"wheelbase_m": 2.65, "track_front_m": 1.6}
MIN_INTERNAL_RATE_HZ = 100.0


def random_params(seed: int, vehicle: Vehicle | None = None) -> Params:
    """A plausible random truth set for a car (seeded): what identification must recover.

    Steering offset uniform in +-0.03 rad, scale in 0.05..0.1. Zones idle [0,2], low (2,5],
    high (5,20] m/s: idle offset +0.15..+0.45 m/s^2 (idle creep), low -0.25..0.0 and high
    -0.45..-0.15 m/s^2 (rolling and aerodynamic drag); throttle scales 1.5..3.0 / 2.0..3.5 /
    2.0..3.5 m/s^2 per full pedal; brake scales 3..6 / 4..7 / 5..8 m/s^2 per full pedal.
    ``vehicle`` defaults to the report's geometry (wheelbase 2.65 m, track 1.6 m).
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EED]))
    veh = vehicle if vehicle is not None else Vehicle(**DEFAULT_VEHICLE)
    u = lambda lo, hi: round(float(rng.uniform(lo, hi)), 4)  # noqa: E731 (readable table below)
    steering = Steering(offset_rad=u(-0.03, 0.03), scale=u(0.05, 0.10))
    table = (
        ("idle", 0.0, 2.0, (0.15, 0.45), (1.5, 3.0), (3.0, 6.0)),
        ("low", 2.0, 5.0, (-0.25, 0.0), (2.0, 3.5), (4.0, 7.0)),
        ("high", 5.0, 20.0, (-0.45, -0.15), (2.0, 3.5), (5.0, 8.0)),
    )
    zones = [
        Zone(
            name=n,
            v_min_mps=lo,
            v_max_mps=hi,
            offset_mps2=u(*o),
            scale_mps2=u(*s),
            brake_scale_mps2=u(*b),
        )
        for n, lo, hi, o, s, b in table
    ]
    return Params(
        vehicle=veh,
        steering=steering,
        zones=zones,
        provenance={"source": "hmpc.models.sim.simulator.random_params", "seed": int(seed)},
    )


@dataclass
class SimRun:
    """A simulated recording with its truth.

    Attributes:
        recording: the canonical recording (what identification sees).
        truth: the plant's truth on the internal grid.
        grid_index: recording row i is truth index ``grid_index[i]`` (same instant).
    """

    recording: Recording
    truth: Truth
    grid_index: np.ndarray = field(repr=False)

    def truth_on_grid(self, name: str) -> np.ndarray:
        """A truth array at the recording's sample times."""
        return self.truth[name][self.grid_index]


def _check_args(name: str, params: Params, rate_hz: float, noise: str, effects) -> None:
    if name not in EXPERIMENTS:
        raise InputError(
            f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})", None, key="experiment"
        )
    if noise not in NOISE_LEVELS:
        raise InputError(
            f"unknown noise level {noise!r} (known: {', '.join(NOISE_LEVELS)})", None, key="noise"
        )
    if not isinstance(params, Params) or not params.is_model:
        raise ParamError(
            "the simulator needs a complete model (steering and longitudinal zones)",
            getattr(params, "path", None),
            key="steering",
        )
    assert params.steering is not None  # is_model
    if params.steering.scale <= 0:
        raise ParamError("steering scale must be positive", params.path, key="steering.scale")
    if not (
        isinstance(rate_hz, numbers.Real) and math.isfinite(rate_hz) and 1.0 <= rate_hz <= 1000.0
    ):
        raise ValueError(f"rate_hz must be within 1..1000 Hz, got {rate_hz!r}")
    for e in effects:
        if not isinstance(e, Effect):
            raise TypeError(f"effects must be models.sim.effect_base.Effect instances, got {e!r}")


# -------------------------------------------------------------------------------- API
def run_experiment(
    name: str,
    params: Params,
    *,
    seed: int = 0,
    rate_hz: float = 50.0,
    noise: str = "typical",
    effects: list[Effect] | None = None,
    driver: DriverConfig | None = None,
) -> SimRun:
    """Simulate experiment ``name`` on the truth ``params``; return the recording and the truth.

    Args:
        name: a key of ``EXPERIMENTS`` (``models.sim.plans``).
        params: the truth: a complete model (steering and zones); geometry from ``vehicle``
            (``track_rear_m`` defaults to ``track_front_m``, full lock to 8.4 rad).
        seed: seeds the driver's randomness, CAN phases/noise and INS noise (printed in meta).
        rate_hz: output grid rate [Hz].
        noise: ``"typical"``, ``"quantised"`` or ``"none"`` (``models.sim.measure``).
        effects: concealed physics (``models.sim.effects``); None or [] for none.
        driver: driver and speed-controller settings (default ``DriverConfig()``).

    Raises:
        InputError: unknown experiment or noise level. ParamError: incomplete params.
        ValueError: rate out of 1..1000 Hz.
    """
    effects = list(effects or [])
    _check_args(name, params, rate_hz, noise, effects)
    driver = driver or DriverConfig()
    m = max(int(math.ceil(MIN_INTERNAL_RATE_HZ / rate_hz - 1e-9)), 1)
    dt = 1.0 / (m * rate_hz)
    ss = np.random.SeedSequence(int(seed))
    rng_plan, rng_drive, rng_can, rng_ins = (np.random.default_rng(s) for s in ss.spawn(4))
    psi0 = float(rng_plan.uniform(-math.pi, math.pi))
    plan = PLANNERS[name](params, dt, rng_plan)
    truth = drive(params, plan, dt, rng_drive, effects, driver, psi0)
    ch, raw, sensor_truth, idx = measure(truth, params, rate_hz, noise, effects, rng_can, rng_ins)
    segments = plan.segments
    meta = {
        "source": "hmpc simulator (models.sim)",
        "experiment": name,
        "description": EXPERIMENTS[name],
        "seed": int(seed),
        "noise": noise,
        "rate_hz": float(rate_hz),
        "internal_rate_hz": float(m * rate_hz),
        "duration_s": float(ch["time"][-1]),
        "params": params.to_dict(),
        "effects": [e.describe() for e in effects],
        "sensor_truth": sensor_truth,
        "ins_point": "front-axle centre (the report's eq. 1 point)",
        "initial_heading_rad": psi0,
        "segments": segments,
        "gaps": [],
    }
    run = SimRun(Recording(ch, raw, meta), truth, idx)
    meta["coverage"] = coverage(run)
    return run


def simulate_experiment(
    name: str,
    params: Params,
    *,
    seed: int = 0,
    rate_hz: float = 50.0,
    noise: str = "typical",
    effects: list[Effect] | None = None,
) -> Recording:
    """A complete canonical recording of experiment ``name`` on the truth ``params``.

    See :func:`run_experiment` for the arguments; ``meta`` holds the truth (``params``,
    ``seed``, ``experiment``, ``effects``, ``sensor_truth``, ``segments``, ``coverage``).
    """
    return run_experiment(
        name, params, seed=seed, rate_hz=rate_hz, noise=noise, effects=effects
    ).recording


def coverage(run: SimRun) -> dict:
    """What a run exercised, from the truth: per zone, seconds moving with throttle, brake or
    neither; steering-wheel angle range per speed band. JSON-friendly."""
    tr = run.truth.arrays
    dt = run.truth.dt_s
    zones = run.recording.meta["params"]["longitudinal"]["zones"]
    moving = tr["v_mps"] > 0.05
    th, br = tr["accel_pedal"] > 0, tr["brake_pedal"] > 0
    out_z = {}
    for i, z in enumerate(zones):
        inz = moving & (tr["zone"] == i)
        out_z[z["name"]] = {
            "moving_s": round(float(inz.sum() * dt), 2),
            "throttle_s": round(float((inz & th).sum() * dt), 2),
            "brake_s": round(float((inz & br).sum() * dt), 2),
            "coast_s": round(float((inz & ~th & ~br).sum() * dt), 2),
            "throttle_max": round(float(tr["accel_pedal"][inz].max()), 3) if inz.any() else 0.0,
            "brake_max": round(float(tr["brake_pedal"][inz].max()), 3) if inz.any() else 0.0,
        }
    bands = {}
    v = tr["v_mps"]
    for lo, hi in ((0.5, 2.0), (2.0, 5.0), (5.0, 20.0)):
        sel = (v > lo) & (v <= hi)
        if sel.any():
            bands[f"{lo:g}-{hi:g} m/s"] = {
                "sw_min_rad": round(float(tr["sw_rad"][sel].min()), 3),
                "sw_max_rad": round(float(tr["sw_rad"][sel].max()), 3),
                "seconds": round(float(sel.sum() * dt), 2),
            }
    return {
        "duration_s": round(float(len(v) * dt), 2),
        "v_max_mps": round(float(v.max()), 3),
        "zones": out_z,
        "steering_by_speed": bands,
    }
