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
    rc = main(
        [
            "identify",
            str(log),
            "--dbc",
            str(dbc),
            "--signals",
            str(signals),
            "--vehicle",
            str(REPORT_PARAMS),
            "--out",
            str(out),
            "--json",
            str(js),
        ]
    )
    assert rc == 0
    return yaml.safe_load(out.read_text()), json.loads(js.read_text())


@pytest.mark.long
def test_steering_map_recovered_from_a_toyota_drive_of_arcs(tmp_path):
    """One Toyota drive of the report's arcs (the first 30 s: clockwise at 2.8 m/s,
    counter-clockwise at 2.4 m/s, III-A.1), read back by ``hmpc identify``; one drive, two
    properties (one test, so that parallel workers never drive it twice)."""
    res, log = drive("toyota", "arcs", 30.0, tmp_path, ref_s=30.5)
    _, j = _identify(
        log,
        DATA_DIR / "dbc/toyota_rav4_2017.dbc.gz",
        PARAMS_DIR / "toyota_rav4_2017.signals.yaml",
        tmp_path,
    )
    summary = res.summary
    assert summary["stop"]["reason"] == "duration", summary["stop"]  # drove the whole 30 s
    assert summary["limit_violations"] == 0
    truth = params().steering
    fits = j["steering"]["fits"]
    print("steering fits", {m: (f["offset_rad"], f["scale"]) for m, f in fits.items()})
    _identify_answer_within_2_percent(j["steering"], truth)
    _yaw_rate_offset_tied_to_the_gyro_bias(fits["yaw_rate"], j["steering"], truth)


def _identify_answer_within_2_percent(st: dict, truth) -> None:
    """The acceptance on identify's own estimate: the wheel-speed-difference fit (the report's
    eqs. 2-6; no gyro bias to trade the offset against) is chosen and within 2 %. (It needs
    the node's wheel speeds to be the rigid body's, ``models.sim.sensors.wheel_speeds``; with
    front wheels at v -+ r T/2 it read +3.7 % at the arcs' 0.27 rad.)"""
    assert st["method"] == "wheel_speed_difference", st["selection"]["because"]
    assert st["identifiability"]["identifiable"], st["identifiability"]["note"]
    assert st["offset_rad"] == pytest.approx(truth.offset_rad, rel=0.02)
    assert st["scale"] == pytest.approx(truth.scale, rel=0.02)


def _yaw_rate_offset_tied_to_the_gyro_bias(yaw: dict, st: dict, truth) -> None:
    """The yaw-rate fit (eq. 7 through eq. 1 against the KINEMATICS yaw rate): scale within the
    acceptance's 2 %. Its offset cannot be held to 2 % on this drive, and identify says so. The
    offset's yaw rate is v tan(offset)/b, the gyro bias estimated with it a constant: only the
    spread of the speeds separates them, and these arcs run at 2.3-2.8 m/s (|corr(offset,
    bias)| ~ 0.998; with the bias fixed at its true 0 the same samples give the offset within
    0.3 %). The node's yaw rate does not dither: each arc reads one 0.244 deg/s level, whose
    rounding error the offset absorbs, so the interval carries it (about +-30 %; without it
    the interval was +-6.5 %, and one CI run missed the truth: 0.01699 < 0.017). The report's
    pair at 5.2 m/s helps but not enough: 34.8 s of the arcs from 18 s (2.4 and 5.2 m/s) gave
    +-2.3 % before the rounding term, |corr| 0.993. Nor can the standstill pin the bias
    on this channel: YAW_RATE's step is 0.244 deg/s and a car at rest reads the step nearest 0
    (-0.072 deg/s, on the node as throughout the real 2019 RAV4's 24 s at rest in tools/data),
    which bounds the bias to +-0.0021 rad/s only: +-12 % of the offset at these speeds
    (d offset / d bias = -b/v)."""
    assert yaw["scale"] == pytest.approx(truth.scale, rel=0.02)
    lo, hi = yaw["offset_ci95_rad"]
    assert lo <= truth.offset_rad <= hi
    # the data cannot hold this offset to 2 %, and identify names the gyro bias as the reason
    assert 0.5 * (hi - lo) > 0.02 * truth.offset_rad, (lo, hi)
    assert abs(yaw["offset_bias_correlation"]) > 0.95
    verdict = st["identifiability_by_fit"]["yaw_rate"]
    assert verdict["scale_identifiable"] and not verdict["offset_identifiable"], verdict
    assert "yaw-rate sensor's bias" in verdict["note"], verdict["note"]


@pytest.mark.long
def test_zone_models_recovered_from_a_bywire_drive_of_ramps(tmp_path):
    res, log = drive("bywire", "ramps", 51.0, tmp_path)
    assert res.summary["limit_violations"] == 0
    got, _ = _identify(
        log, PARAMS_DIR / "hmpc_bywire.dbc", PARAMS_DIR / "hmpc_bywire.signals.yaml", tmp_path
    )
    zones = {z["name"]: z for z in got["longitudinal"]["zones"]}
    for z in params().zones:
        g = zones[z.name]
        print(z.name, g["offset_mps2"], g["scale_mps2"], g["brake_scale_mps2"])
        # the acceptance tolerances: offsets within 0.05 m/s^2, scales within 5 %
        assert g["offset_mps2"] == pytest.approx(z.offset_mps2, abs=0.05), z.name
        for key in ("scale_mps2", "brake_scale_mps2"):
            assert g[key] == pytest.approx(getattr(z, key), rel=0.05), (z.name, key)
