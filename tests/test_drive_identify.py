"""Closing the loop: ``hmpc ingest`` + ``hmpc identify`` read the candump of drives of the
report's experiments on the vehicle simulator node and recover the simulated car's parameters
(params/report_2008.yaml): the steering map from the Toyota path (arcs; KINEMATICS yaw rate),
the zone models from the by-wire path (ramps; the kit reports continuous pedal positions, the
Toyota's brake is a switch). Real time: about 1.5 minutes."""
from __future__ import annotations

import json

import pytest
import yaml

from _data import DATA_DIR, PARAMS_DIR, REPORT_PARAMS
from _drive import drive, params
from hmpc.tools.cli import main

pytestmark = pytest.mark.realtime


def _identify(log, dbc, signals, tmp_path):
    out, js = tmp_path / "id.yaml", tmp_path / "id.json"
    rc = main(["identify", str(log), "--dbc", str(dbc), "--signals", str(signals),
               "--vehicle", str(REPORT_PARAMS), "--out", str(out), "--json", str(js)])
    assert rc == 0
    return yaml.safe_load(out.read_text()), json.loads(js.read_text())


def test_steering_map_recovered_from_a_toyota_drive_of_arcs(tmp_path):
    res, log = drive("toyota", "arcs", 30.0, tmp_path, ref_s=30.5)
    assert res.summary["limit_violations"] == 0
    _, j = _identify(log, DATA_DIR / "dbc/toyota_rav4_2017.dbc.gz",
                     PARAMS_DIR / "toyota_rav4_2017.signals.yaml", tmp_path)
    truth = params().steering
    fits = j["steering"]["fits"]
    print("steering fits", {m: (f["offset_rad"], f["scale"]) for m, f in fits.items()})
    # the yaw-rate fit (eq. 7 through eq. 1 against the KINEMATICS yaw rate): scale within 2 %.
    # Its offset trades against the gyro bias it estimates too (identify calls the offset not
    # identifiable on 30 s of arcs), so only the scale is held to the 2 % here.
    assert fits["yaw_rate"]["scale"] == pytest.approx(truth.scale, rel=0.02)
    lo, hi = fits["yaw_rate"]["offset_ci95_rad"]
    assert lo <= truth.offset_rad <= hi


def test_zone_models_recovered_from_a_bywire_drive_of_ramps(tmp_path):
    res, log = drive("bywire", "ramps", 51.0, tmp_path)
    assert res.summary["limit_violations"] == 0
    got, _ = _identify(log, PARAMS_DIR / "hmpc_bywire.dbc",
                       PARAMS_DIR / "hmpc_bywire.signals.yaml", tmp_path)
    zones = {z["name"]: z for z in got["longitudinal"]["zones"]}
    for z in params().zones:
        g = zones[z.name]
        print(z.name, g["offset_mps2"], g["scale_mps2"], g["brake_scale_mps2"])
        # the tolerances: offsets within 0.05 m/s^2, scales within 5 %
        assert g["offset_mps2"] == pytest.approx(z.offset_mps2, abs=0.05), z.name
        for key in ("scale_mps2", "brake_scale_mps2"):
            assert g[key] == pytest.approx(getattr(z, key), rel=0.05), (z.name, key)
