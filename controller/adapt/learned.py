"""The online model estimator's state as a parameter file (``--learned FILE``): restored at the
start of a run and saved at its end, one file per vehicle, as openpilot's paramsd keeps its
estimate across drives.

The file is an ordinary parameter file (``models.params``, the conventions' keys), so that
``identify``, ``diagnose`` and ``fleet`` read it: the steering map and the zones hold the values
in use at the end (the learned ones while valid, the starting file's otherwise), with their
95 % intervals (``offset_ci95_rad``, ``scale_ci95``, ``*_ci95_mps2``: the state restored next
time); learned dead times are ``steering.dead_time_s`` / ``longitudinal.dead_time_s`` (what the
controller reads) and ``extensions.actuator_delay``, learned lags ``extensions.actuator_lag``,
each with its interval; ``provenance`` says where it came from. A file hmpc would refuse is
never written: the content is validated by the loader first, written to a temporary file
beside the target and renamed over it (a crash leaves the old file or the new one, never half
of one).

A learned file belongs to one vehicle: its geometry and zones must be the model's
(:func:`restore`); the bounds of a restored run stay those of the file the controller was
given, so a learned state cannot walk away from it over many drives.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import replace
from pathlib import Path

import yaml

from hmpc.models.errors import InputError
from hmpc.models.params import Params, parse_params

from hmpc.controller.adapt.adapter import ModelAdapter
from hmpc.controller.adapt.steering import OFFSET, SCALE

#: [1] a restored 95 % interval that is this narrow relative to the prior is widened to it
#: over a day: the car may have been loaded, re-tyred or aligned between drives. Restoring
#: keeps at least this fraction of the prior 1-sigma.
RESTORE_MIN_SIGMA_FRACTION = 0.1


def _same_vehicle(params: Params, learned: Params, path: str) -> None:
    """InputError unless ``learned`` is a state of the vehicle ``params`` describes."""
    a, b = params.vehicle, learned.vehicle
    for key in ("wheelbase_m", "track_front_m"):
        if abs(getattr(a, key) - getattr(b, key)) > 1e-6:
            raise InputError(
                f"learned for another vehicle ({key} {getattr(b, key):g}, the "
                f"model's {getattr(a, key):g})",
                path,
            )
    za = [(z.name, z.v_min_mps, z.v_max_mps) for z in params.zones]
    zb = [(z.name, z.v_min_mps, z.v_max_mps) for z in learned.zones]
    if za != zb:
        raise InputError(
            f"learned with other zones than the model's ({', '.join(n for n, *_ in zb)})", path
        )


def _sigma(ci, value: float, prior: float) -> float:
    """1-sigma from a 95 % interval (the prior's when absent), not below a fraction of it."""
    if ci is None:
        return prior
    s = 0.5 * (float(ci[1]) - float(ci[0])) / 1.96
    return max(s, RESTORE_MIN_SIGMA_FRACTION * prior) if math.isfinite(s) else prior


def restore(adapter: ModelAdapter, learned: Params, path: str) -> list[str]:
    """Start ``adapter`` from a learned file (module docstring); returns what was restored,
    one line each. Raises InputError for another vehicle's file."""
    params = adapter.params
    _same_vehicle(params, learned, path)
    notes = []
    f = adapter.steering.filter
    st = learned.steering
    prior = [math.sqrt(c) for c in f.cap]
    assert st is not None
    f.restore(
        [st.offset_rad, st.scale],
        [
            _sigma(st.offset_ci95_rad, st.offset_rad, prior[OFFSET]),
            _sigma(st.scale_ci95, st.scale, prior[SCALE]),
        ],
    )
    notes.append(f"steering offset {f.theta[OFFSET]:.4f} rad, scale {f.theta[SCALE]:.4f}")
    zl = adapter.zones
    for zi, (z, zf) in enumerate(zip(learned.zones, zl.filters)):
        prior = [math.sqrt(c) for c in zf.cap]
        if zl.inputs == "pedals":
            zf.restore(
                [z.offset_mps2, z.scale_mps2, z.brake_scale_mps2],
                [
                    _sigma(z.offset_ci95_mps2, z.offset_mps2, prior[0]),
                    _sigma(z.scale_ci95_mps2, z.scale_mps2, prior[1]),
                    _sigma(z.brake_scale_ci95_mps2, z.brake_scale_mps2, prior[2]),
                ],
            )
        else:  # the command response of eq. 8 of the file: gain, then offset
            fz = params.zones[zi]
            g = z.scale_mps2 / fz.scale_mps2
            ci = z.scale_ci95_mps2
            zf.restore(
                [z.offset_mps2 - g * fz.offset_mps2, g],
                [
                    _sigma(z.offset_ci95_mps2, 0.0, prior[0]),
                    _sigma(None if ci is None else [c / fz.scale_mps2 for c in ci], g, prior[1]),
                ],
            )
        notes.append(f"zone {z.name}: " + ", ".join(f"{x:.3f}" for x in zf.theta))
    timing = _learned_timing(learned)
    if timing:
        for i, v in timing.items():
            adapter.timing_used[i] = v
        adapter.zones.use_timing(adapter.timing_used[1], adapter.timing_used[3])
        notes.append("dead times and lags " + ", ".join(f"{v:.2f} s" for v in adapter.timing_used))
    adapter.initial = adapter._values_now()
    adapter._force_push = True  # the restored model is handed over at the first step
    return notes


def _learned_timing(learned: Params) -> dict:
    """{index in ``ModelAdapter.timing_used``: value} of the dead times and lags a learned
    file holds with an interval (learned ones; a value without one is the file's own)."""
    out = {}
    x = learned.extensions or {}
    for eid, key, subs in (
        ("actuator_delay", "delay_s", {"steering": 0, "longitudinal": 1}),
        ("actuator_lag", "tau_s", {"steering": 2, "longitudinal": 3}),
    ):
        for sub, i in subs.items():
            ent = x.get(eid, {}).get(sub, {})
            if key in ent and key in ent.get("intervals", {}):
                out[i] = float(ent[key])
    return out


def learned_params(adapter: ModelAdapter, *, run_s: float = 0.0) -> Params:
    """The adapter's state now as a parameter file of the model's vehicle (module
    docstring)."""
    adapter._drift_all()
    adapter._check_validity()
    p = adapter.params
    u = adapter._used_values()
    nz = len(p.zones)
    f = adapter.steering.filter

    def ci(filt, i, value):
        s = 1.96 * filt.sigma(i)
        return (value - s, value + s)

    assert p.steering is not None
    steering = replace(
        p.steering,
        offset_rad=u[0],
        scale=u[1],
        offset_ci95_rad=ci(f, OFFSET, u[0]),
        scale_ci95=ci(f, SCALE, u[1]),
        dead_time_s=_timing_value(adapter, 0, p.steering.dead_time_s),
        note=_note(adapter, [0, 1]),
    )
    zones = []
    nc = len(adapter._coefs)
    for zi, (z, zf) in enumerate(zip(p.zones, adapter.zones.filters)):
        off, sc, br = u[2 + zi], u[2 + nz + zi], u[2 + 2 * nz + zi]
        if adapter.zones.inputs == "pedals":
            cis = {
                "offset_ci95_mps2": ci(zf, 0, off),
                "scale_ci95_mps2": ci(zf, 1, sc),
                "brake_scale_ci95_mps2": ci(zf, 2, br),
            }
        else:  # the gain's interval scales the file's pedal gains
            g_s = 1.96 * zf.sigma(1)
            cis = {
                "offset_ci95_mps2": ci(zf, 0, off),
                "scale_ci95_mps2": (sc - g_s * z.scale_mps2, sc + g_s * z.scale_mps2),
                "brake_scale_ci95_mps2": (
                    br - g_s * z.brake_scale_mps2,
                    br + g_s * z.brake_scale_mps2,
                ),
            }
        js = list(range(2 + zi * nc, 2 + (zi + 1) * nc))
        zones.append(
            replace(
                z,
                offset_mps2=off,
                scale_mps2=sc,
                brake_scale_mps2=br,
                samples=float(max(zf.updates)),
                note=_note(adapter, js),
                **cis,
            )
        )
    ext = {k: {s: dict(v) for s, v in subs.items()} for k, subs in (p.extensions or {}).items()}
    for ch, i_d, i_l in (("steering", 0, 2), ("longitudinal", 1, 3)):
        est = adapter.timing_est[ch]
        if est is None or not est["valid"]:
            continue
        ext.setdefault("actuator_delay", {})[ch] = {
            "delay_s": adapter.timing_used[i_d],
            "intervals": {"delay_s": list(est["delay_ci95_s"])},
        }
        ext.setdefault("actuator_lag", {})[ch] = {
            "tau_s": adapter.timing_used[i_l],
            "intervals": {"tau_s": list(est["lag_ci95_s"])},
        }
    prov = {
        "source": "hmpc online model estimator (controller/adapt)",
        "started_from": str(p.path),
        "run_s": round(float(run_s), 3),
    }
    return replace(
        p,
        steering=steering,
        zones=zones,
        longitudinal_dead_time_s=_timing_value(adapter, 1, p.longitudinal_dead_time_s),
        extensions=ext,
        provenance=prov,
        not_identified={},
        path=None,
    )


def _timing_value(adapter: ModelAdapter, i: int, file_value):
    """Dead time ``i`` (0 steering, 1 longitudinal) in use when learned, else the file's."""
    used = adapter.timing_used[i]
    return used if used != adapter.timing_file[i] else file_value


def _note(adapter: ModelAdapter, js: list) -> str:
    """One line on how the values of parameters ``js`` were obtained."""
    keys = [adapter._plist[j][0].rsplit(".", 1)[-1] for j in js]
    learned = [k for k, j in zip(keys, js) if adapter.identified[j]]
    if not any(adapter.valid[j] for j in js):
        return "learned on line: no data taught these values yet; the starting file's"
    if learned:
        return f"learned on line; identified: {', '.join(learned)}"
    return "learned on line; none identified alone (their combination is)"


def save_learned(params: Params, path: str | Path) -> str:
    """Write ``params`` to ``path`` only if hmpc would load it: validated, written to a
    temporary file in the same folder and renamed over ``path``. InputError when it cannot
    be written; ParamError (a bug) when the content would be refused."""
    path = Path(path)
    data = params.to_dict()
    parse_params(data, str(path), require_model=True)  # never write a file hmpc refuses
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None)
    folder = path.parent if str(path.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
    except OSError as exc:
        raise InputError(
            f"cannot write the learned state ({exc.strerror or exc})", str(path)
        ) from None
    return str(path)
