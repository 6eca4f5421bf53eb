"""The parameter files ``hmpc diagnose`` writes: the extended model (:func:`extended_params`:
the findings in the ``extensions:`` section, :func:`extensions_section`, with the
coefficients each was fitted with, and the conventions' keys as a tool that ignores
``extensions:`` should use them) and the report's baseline fitted on the recording as it
came (:func:`baseline_params`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any
from types import SimpleNamespace

from hmpc.models.catalogue import CATALOGUE
from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose import steering as ste
from hmpc.models.diagnose.lon_inputs import COMMANDS
from hmpc.models.errors import InputError
from hmpc.models.params import Params, Steering, Zone

#: longitudinal findings whose fit the conventions' keys take (see :func:`extended_params`)
_KEYS_HOLD = ("actuator_delay", "road_grade")


def extensions_section(findings: list, longitudinal_input: str) -> dict:
    """The findings as a parameter file's ``extensions:`` section (models.params): catalogue
    id -> subsystem -> its catalogue parameters, their intervals, the equation and, for the
    longitudinal part, the input the model is driven by."""
    out: dict = {}
    for f in findings:
        names = CATALOGUE[f["effect"]]["parameters"]
        e: dict[str, Any] = {k: float(v) for k, v in f["parameters"].items() if k in names}
        iv = {k: [float(a), float(b)] for k, (a, b) in f["intervals"].items() if k in names}
        if iv:
            e["intervals"] = iv
        e["equation"] = f["equation"]
        if f["subsystem"] == "longitudinal" and f["channel"] == "speed":
            e["input"] = longitudinal_input
        if isinstance(f["parameters"].get("grade_source"), str):
            e["grade_source"] = f["parameters"]["grade_source"]
        below = next(iter(f.get("on_top_of", {})), None)
        if below is not None:
            e["on_top_of"] = below
        out.setdefault(f["effect"], {})[f["subsystem"]] = e
    return out


def baseline_params(rec, vehicle, params, zones, cfg, not_diagnosed: dict | None = None) -> Params:
    """The report's model fitted on the uncorrected recording (no finding, no sensor fix); the
    parts in ``not_diagnosed`` are left as the given file has them (or absent)."""
    nd = not_diagnosed or {}
    ch = dict(rec.channels)
    sdt = None if "steering" in nd else ste.prepare(ch, vehicle.wheelbase_m, cfg)
    steer = None if sdt is None else {None: SimpleNamespace(model=ste.fit(sdt, None, 0.0, sdt.ok))}
    ld, lon_scores = None, {}
    if "longitudinal" not in nd:
        ld = lon.prepare(ch, zones, cfg)
        lon_scores = {None: SimpleNamespace(model=lon.fit(ld, lon.LonSpec(), ld.ok))}
    p = extended_params(rec, vehicle, params, ld, lon_scores, steer, [], zones, cfg, nd)
    p.provenance["source"] = "hmpc diagnose (the report's baseline, no findings)"
    return p


def extended_params(
    rec,
    vehicle,
    params,
    ld,
    lon_scores,
    steer_scores,
    findings,
    zones,
    cfg,
    not_diagnosed: dict | None = None,
) -> Params:
    """The extended model: the findings in the parameter file's ``extensions:`` section
    (models.params), and the conventions' keys (steering map, zones, dead times) as a tool that
    ignores ``extensions:`` should use them: fitted with a dead time (which the keys hold) or
    with the road grade taken out (a disturbance of this road, not of the car: another road
    has another grade); for the car's own terms the keys cannot hold (lag, drag, creep, a
    steering-map shape) the baseline's fit, whose coefficients absorb them at the speeds and
    angles driven (the jointly fitted coefficients without the term would be worse there).

    The given file's status flags stay (:func:`_keep_status`): a value it flags
    ``identifiable: false`` stays flagged, its ``not_identified:`` entries stay. A part this
    recording could not diagnose (``not_diagnosed``, ``ld`` or ``steer_scores`` None) is the
    given file's, or absent and named under ``not_identified:``."""
    nd = not_diagnosed or {}
    fx = {(f["effect"], f["subsystem"]): f for f in findings}
    steering = params.steering if params is not None else None
    if steer_scores is not None:
        best = "actuator_delay" if ("actuator_delay", "steering") in fx else None
        m = steer_scores[best].model
        steering = Steering(
            offset_rad=float(m.offset_rad),
            scale=float(m.scale),
            method=f"hmpc diagnose ({best or 'baseline'})",
        )
        if best == "actuator_delay":
            steering.dead_time_s = float(m.delay_s)
    zs = params.zones if params is not None and ld is None else []
    if ld is not None:
        zs = _zones_out(rec, params, ld, lon_scores, findings, zones, cfg)
        if not zs:
            nd = {
                **nd,
                "longitudinal": "no accel_pedal channel: the zones' pedal maps cannot "
                f"be fitted (the car is driven by "
                f"{'+'.join(ld.input_names)})",
            }
    p = Params(
        vehicle=replace(vehicle),
        steering=steering,
        zones=zs,
        provenance={"source": "hmpc diagnose", "recording": str(rec.meta.get("path", "?"))},
    )
    if ld is not None and ("actuator_delay", "longitudinal") in fx and not ld.commanded:
        p.longitudinal_dead_time_s = float(
            fx[("actuator_delay", "longitudinal")]["parameters"]["delay_s"]
        )
    _keep_status(p, params, steer_scores is not None, ld is not None)
    for part in ("steering", "longitudinal"):
        if part in nd and (
            part == "steering" and p.steering is None or part == "longitudinal" and not p.zones
        ):
            p.not_identified[part] = f"not diagnosed: {nd[part]}"
    p.extensions = extensions_section(findings, "" if ld is None else "+".join(ld.input_names))
    for f in findings:  # each entry carries the coefficients it was fitted jointly with
        e = p.extensions[f["effect"]][f["subsystem"]]
        if (
            f["subsystem"] == "steering"
            and steer_scores is not None
            and f["effect"] in steer_scores
        ):
            sm = steer_scores[f["effect"]].model
            e["base"] = {"offset_rad": float(sm.offset_rad), "scale": float(sm.scale)}
        elif f["channel"] == "speed":
            sc = lon_scores.get(("on_top", f["effect"])) or lon_scores[f["effect"]]
            e["base"] = {"zones": _base_zones(sc.model, ld.input_names, zones)}
    return p


def _zones_out(rec, params, ld, lon_scores, findings, zones, cfg) -> list[Zone]:
    """The zones of eq. 8 as the conventions' keys hold them (see :func:`extended_params`)."""
    d_pedal = ld
    if ld.commanded:  # the conventions' zones are pedal maps
        ch = {k: v for k, v in rec.channels.items() if k not in COMMANDS}
        try:
            d_pedal = lon.prepare(ch, zones, cfg)
        except InputError:
            d_pedal = None
    if d_pedal is None or "accel_pedal" not in d_pedal.input_names:
        return list(params.zones) if params is not None and params.zones else []
    names = d_pedal.input_names
    best_lon = next(
        (
            f["effect"]
            for f in findings
            if f["subsystem"] == "longitudinal"
            and f["channel"] == "speed"
            and f["effect"] in _KEYS_HOLD
        ),
        None,
    )
    if d_pedal is ld:
        m = lon_scores[best_lon].model
    else:
        m = lon.fit(d_pedal, lon.LonSpec(), d_pedal.ok)
    zs = []
    for i, (nm, lo, hi) in enumerate(zones):
        c = m.C[i]
        z = Zone(
            name=nm,
            v_min_mps=float(lo),
            v_max_mps=float(hi),
            offset_mps2=float(c[0]),
            scale_mps2=float(c[1 + names.index("accel_pedal")]),
            brake_scale_mps2=float(c[1 + names.index("brake_pedal")])
            if "brake_pedal" in names
            else 0.0,
            identifiable=bool(i in m.fitted_zones),
        )
        if params is not None and params.zones:  # what this recording cannot tell: as given
            g = params.zones[i]
            if i not in m.fitted_zones:
                z.offset_mps2, z.scale_mps2, z.brake_scale_mps2 = (
                    g.offset_mps2,
                    g.scale_mps2,
                    g.brake_scale_mps2,
                )
                z.note = "not in this recording: kept from the given parameter file"
            elif z.brake_scale_mps2 == 0.0:
                z.brake_scale_mps2 = g.brake_scale_mps2
                z.note = "brake not used in this recording: brake scale kept from the given file"
        elif "brake_pedal" not in names:
            z.note = "no brake_pedal channel: brake scale unknown (0 written)"
        elif z.brake_scale_mps2 == 0.0:
            z.note = "brake not used in this recording: brake scale unknown (0 written)"
        zs.append(z)
    return zs


def _keep_status(p: Params, given: Params | None, steering_refit: bool, zones_refit: bool) -> None:
    """The given file's status flags on ``p``: a refitted steering map or zone the given file
    flags ``identifiable: false`` stays flagged (with the given note beside diagnose's), and its
    ``not_identified:`` entries for what ``p`` still lacks or still flags stay."""
    if given is None:
        return

    def why(note: str | None) -> str:
        note = (note or "no reason given").strip()
        return (
            note[len("NOT identifiable:") :].strip()
            if note.startswith("NOT identifiable:")
            else note
        )

    gs = given.steering
    if steering_refit and gs is not None and gs.identifiable is False:
        assert p.steering is not None
        p.steering.identifiable = False
        p.steering.note = (
            "refitted by hmpc diagnose on this recording; the given file flags "
            f"it not identifiable: {why(gs.note)}"
        )
    if zones_refit and given.zones:
        for z, g in zip(p.zones, given.zones):
            if g.identifiable is False and z.identifiable is not False:
                z.identifiable = False
                z.note = "; ".join(
                    x
                    for x in (z.note, f"the given file flags it not identifiable: {why(g.note)}")
                    if x
                )
    flagged = {z.name for z in p.zones if z.identifiable is False}
    for k, why in given.not_identified.items():
        if k == "steering" and p.steering is None or k == "longitudinal" and not p.zones:
            p.not_identified[k] = why
        elif k.startswith("longitudinal.zones."):
            name = k[len("longitudinal.zones.") :].rpartition(".")[0]
            if name in flagged:
                p.not_identified[k] = why


def _base_zones(m: lon.LonModel, names: list, zones) -> list[dict]:
    """Per zone the offset and one gain per input of ``m`` (``models.params``' ``base``)."""
    key = {
        "accel_pedal": "scale_mps2",
        "brake_pedal": "brake_scale_mps2",
        "accel_cmd": "accel_cmd_gain",
        "speed_cmd": "speed_cmd_gain_ps",
    }
    if m.spec.by_gear:  # one coefficient set per gear (``gears``)
        zones = [(f"gear_{i + 1}", 0.0, 0.0) for i in range(len(m.C))]
    out = []
    for i, (nm, _, _) in enumerate(zones):
        z = {"name": nm, "offset_mps2": float(m.C[i, 0])}
        if m.C.shape[1] > 1 + len(names):  # the released pedal's column of ``gears``
            z["engine_braking_per_krpm_mps2"] = float(m.C[i, -1])
        for j, inp in enumerate(names):
            g = float(m.C[i, 1 + j])
            # U holds -brake_pedal (longitudinal.py), so the gain on it is the report's
            # positive brake scale: dv/dt = offset + scale * ap - brake_scale * bp
            z[key[inp]] = g
        out.append(z)
    return out
