"""The overall verdict: does the report's model, with every finding added, describe this vehicle?

Per free-run channel (heading, speed) the final held-out RMSE (the best finding's on that
channel, else the baseline's) is set against two yardsticks:

- the channel's noise floor (``locate.noise_floor``): ``factor = rmse / noise_floor``;
- persistence, the prediction that nothing changes over the window (the measured value at
  the window's start held): ``skill = 1 - rmse / rmse_persistence``.

A model misses a channel when its error is far above what the sensor can resolve
(``factor >= MIN_FACTOR``), it predicts the channel hardly better than holding its first value
(``skill < MIN_SKILL``) and the error is material (:data:`MATERIAL`): then nothing in the
catalogue explains what the vehicle does, and the verdict is "this model does not describe this
vehicle", naming the channels and factors. A model that tracks a channel but not to its noise
floor (a real car is never exactly the report's model) keeps a high skill and passes.
"""

from __future__ import annotations

import numpy as np

from hmpc.models.diagnose.common import DiagnoseConfig, rmse, windows
from hmpc.models.diagnose.display import shown

#: free-run channels judged, with the window config field each was replayed over
CHANNELS = {"heading": "window_steer_s", "speed": "window_lon_s"}
#: [1] a final error at least this many times the noise floor is far above it: the floors are
#: white-noise deviations of single samples, a free run over seconds accumulates a few of them
#: and model error of a few per cent adds more; an order of magnitude is beyond both
MIN_FACTOR = 10.0
#: smallest final error that can be a miss, per channel [its unit]: a channel that hardly moves
#: over a window (a straight road's heading) is predicted by holding it as well as by any model,
#: and an error this small is a model's ordinary offset, not a vehicle it does not describe.
#: Heading 0.05 rad (3 deg: at 20 m/s over 5 s, 5 m sideways); speed 0.2 m/s (scaled by
#: sqrt(wheelbase / 2.65 m) below a passenger car's size, like the speed thresholds,
#: ``DiagnoseConfig.for_vehicle``)
MATERIAL = {"heading": 0.05, "speed": 0.2}
#: [1] skill below which the model predicts the channel no better than holding its first value
#: over the window (1: perfect, 0: as good as persistence, < 0: worse): a model of the vehicle
#: explains at least half of how the channel moves
MIN_SKILL = 0.5


def persistence_rmse(measured: np.ndarray, err: np.ndarray, length: int) -> float:
    """RMSE of holding the measured value at each window's start over windows of ``length``
    samples tiling the runs where ``err`` (the held-out error) is finite."""
    idx = windows(np.isfinite(err) & np.isfinite(measured), length)
    if idx.size == 0:
        return float("nan")
    return rmse(measured[idx] - measured[idx[:, :1]])


def model_verdict(
    channels: dict, series: dict, findings: list, cfg: DiagnoseConfig, size: float = 1.0
) -> dict:
    """``{model_describes_vehicle, channels: {name: {rmse, noise_floor, factor,
    rmse_persistence, skill, misses}}, text}`` (``model_describes_vehicle`` None when no
    free-run channel was replayed; ``size``: ``common.size_factor`` of the vehicle)."""
    t = series.get("t")
    out: dict = {}
    for name, window_key in CHANNELS.items():
        c, s = channels.get(name), series.get(name)
        if c is None or s is None or "measured" not in s or t is None or len(t) < 2:
            continue
        base = c.get("heldout_rmse_baseline")
        after = [f["heldout_rmse_after"] for f in findings if f["channel"] == name]
        final = min([base] + after) if base is not None else None
        floor = c.get("noise_floor")
        if final is None or not np.isfinite(final):
            continue
        L = int(c.get("window_s", getattr(cfg, window_key)) / (t[1] - t[0]))
        naive = persistence_rmse(np.asarray(s["measured"], float), s["before"], L)
        factor = final / floor if floor and np.isfinite(floor) and floor > 0 else float("inf")
        skill = 1.0 - final / naive if np.isfinite(naive) and naive > 0 else float("nan")
        material = MATERIAL[name] * (np.sqrt(size) if name == "speed" else 1.0)
        misses = bool(factor >= MIN_FACTOR and not skill >= MIN_SKILL and final >= material)
        out[name] = {
            "unit": c.get("unit"),
            "rmse": final,
            "noise_floor": floor,
            "factor": factor,
            "rmse_persistence": naive,
            "skill": skill,
            "material": material,
            "misses": misses,
        }
    if not out:
        return {
            "model_describes_vehicle": None,
            "channels": {},
            "text": "no free-run channel was replayed: no verdict",
        }
    missed = {k: v for k, v in out.items() if v["misses"]}
    if missed:
        text = (
            "this model does not describe this vehicle: "
            + "; ".join(
                f"{k} error {_q(v['rmse'], v['unit'])} is {v['factor']:.0f} x its noise floor "
                f"{_q(v['noise_floor'], v['unit'], '.2g')} and predicts it "
                f"{'no' if v['skill'] <= 0 else 'hardly'} better than holding its first value "
                f"(skill {v['skill']:.2f})"
                for k, v in missed.items()
            )
            + "; nothing in the catalogue explains it"
        )
    else:
        text = "the model describes this vehicle: " + "; ".join(
            f"{k} error {_q(v['rmse'], v['unit'])}, "
            + (
                f"{100 * v['skill']:.0f} % better than holding its first value"
                if v["skill"] >= MIN_SKILL
                else f"below the {_q(v['material'], v['unit'])} that would be a miss"
                if v["rmse"] < v["material"]
                else f"{v['factor']:.1f} x its noise floor"
            )
            for k, v in out.items()
        )
    return {"model_describes_vehicle": not missed, "channels": out, "text": text}


def _q(value: float, unit: str, fmt: str = ".3g") -> str:
    """A value as shown to people (angles in deg)."""
    v, u = shown(value, unit)
    return f"{v:{fmt}} {u}"
