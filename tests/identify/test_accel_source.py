"""The acceleration source of the zone models is chosen by held-out evidence.

Recordings come from the independent CommonRoad simulator (``tests/indep/commonroad_truth.py``,
truth set B, INS at the rear axle, seed 22), where the three sources (front wheel speeds, GNSS
ground speed, INS ``accel_x``) all measure the truth. One source is then corrupted the way a
real installation corrupts it, and the choice must move away from it:

- wheel speeds 5 % high (a wrong tyre radius in the car's wheel-speed scaling);
- GNSS speed 0.3 s late (receiver latency).

Figures measured when written (seed 22): clean, wheel_speeds chosen (score 0.000 m/s^2; GNSS
0.003, accel_x 0.0025); tyre radius, gps_speed chosen (0.021 against wheel_speeds 0.029) with
every zone scale within 2.3 % of the truth; GNSS latency, wheel_speeds chosen (0.146 against
gps_speed 0.201) and the GNSS source's own dead time 0.31 s.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from hmpc.models.errors import InputError
from hmpc.models.identify.longitudinal import LongitudinalIdConfig, identify_longitudinal
from hmpc.models.logs.recording import Recording
from hmpc.models.params import load_params, parse_params
from hmpc.tools import cli
from indep import commonroad_truth as ct

TRUTH = "B"
REF = "rear"
WHEELS = ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr")
#: the acceptance tolerances of a zone
ZONE_SCALE_TOL = 0.05
ZONE_OFFSET_TOL_MPS2 = 0.05


@pytest.fixture(scope="module")
def channels():
    return ct.record(ct.scenario(TRUTH, ref_point=REF))


@pytest.fixture(scope="module")
def vehicle():
    return parse_params(ct.geometry()).vehicle


def _identify(ch, vehicle, **cfg):
    rec = Recording({k: np.asarray(v).copy() for k, v in ch.items()}, {}, {"path": "indep.csv"})
    return identify_longitudinal(rec, vehicle, LongitudinalIdConfig(**cfg))


def _tyre_radius_wrong(ch, factor=1.05):
    out = dict(ch)
    for k in WHEELS:
        out[k] = ch[k] * factor
    return out


def _gnss_late(ch, delay_s=0.3, rate_hz=50.0):
    n = int(round(delay_s * rate_hz))
    out = dict(ch)
    out["gps_speed"] = np.concatenate([np.full(n, ch["gps_speed"][0]), ch["gps_speed"][:-n]])
    return out


def _within_truth(res):
    for z, t in zip(res.zones, ct.TRUTHS[TRUTH].zones):
        assert abs(z.offset_mps2 - t.offset_mps2) <= ZONE_OFFSET_TOL_MPS2, z
        assert abs(z.scale_mps2 / t.scale_mps2 - 1.0) <= ZONE_SCALE_TOL, z


def test_clean_recording_scores_every_source_and_keeps_the_wheel_speeds(channels, vehicle):
    res = _identify(channels, vehicle)
    sel = res.report["selection"]
    print({k: v["score_mps2"] for k, v in sel["scores"].items()}, sel["because"])
    assert set(sel["scores"]) == {"wheel_speeds", "gps_speed", "accel_x"}
    assert "speed" in sel["skipped"]  # the same wheel sensors: not an independent source
    assert sel["chosen"] == "wheel_speeds"
    assert res.accel_source.startswith("d/dt of the front-axle-centre speed")
    assert not sel["disagreements"]["statements"]
    _within_truth(res)
    assert all(z.identifiable for z in res.zones)


def test_a_wrong_tyre_radius_moves_the_choice_off_the_wheel_speeds(channels, vehicle):
    res = _identify(_tyre_radius_wrong(channels), vehicle)
    sel = res.report["selection"]
    sc = {k: v["score_mps2"] for k, v in sel["scores"].items()}
    print(sc, sel["because"], sel["disagreements"]["statements"])
    assert sel["chosen"] != "wheel_speeds"
    assert sc["wheel_speeds"] > sc[sel["chosen"]]
    _within_truth(res)
    # the outvoted source is named with the likely cause
    text = " ".join(sel["disagreements"]["statements"])
    assert "wheel_speeds" in text and "tyre radius" in text


def test_gnss_latency_moves_the_choice_off_the_gnss_speed_and_shows_as_its_dead_time(
    channels, vehicle
):
    res = _identify(_gnss_late(channels), vehicle)
    sel = res.report["selection"]
    sc = sel["scores"]
    print({k: (v["score_mps2"], v["dead_time_s"]) for k, v in sc.items()})
    assert sel["chosen"] != "gps_speed"
    assert sc["gps_speed"]["score_mps2"] > sc[sel["chosen"]]["score_mps2"]
    assert sc["gps_speed"]["dead_time_s"] == pytest.approx(0.3, abs=0.03)
    assert res.dead_time_s < 2 / 50.0  # the pedals themselves have no dead time
    _within_truth(res)


def test_two_sources_that_disagree_with_no_third_are_not_identifiable(channels, vehicle):
    """Wheel speeds 5 % high and the GNSS speed, no accel_x: nothing says which is right, so
    the zones whose scales differ beyond their intervals are not called identifiable."""
    ch = _tyre_radius_wrong(channels)
    del ch["accel_x"]
    res = _identify(ch, vehicle)
    dis = res.report["selection"]["disagreements"]["zones"]
    flagged = [z for z in res.zones if dis.get(z.name, {}).get("disagree")]
    assert flagged, dis
    for z in flagged:
        assert z.identifiable is False and "disagree" in z.note, z.note


def test_without_wheel_speeds_the_other_sources_compete(channels, vehicle):
    ch = {k: v for k, v in channels.items() if k not in WHEELS}
    res = _identify(ch, vehicle)
    sel = res.report["selection"]
    assert set(sel["scores"]) == {"speed", "gps_speed", "accel_x"}
    assert "wheel_speed_fl" in sel["skipped"]["wheel_speeds"]
    assert res.report["speed_source"] == "CAN 'speed' channel"
    _within_truth(res)


def test_a_configured_source_is_used_and_an_absent_one_named(channels, vehicle):
    res = _identify(channels, vehicle, accel_source="gps_speed")
    assert res.report["selection"]["chosen"] == "gps_speed"
    assert "configuration" in res.report["selection"]["because"]
    ch = {k: v for k, v in channels.items() if k != "accel_x"}
    with pytest.raises(InputError, match="accel_x"):
        _identify(ch, vehicle, accel_source="accel_x")


def test_the_choice_and_every_score_reach_the_json_the_file_and_the_summary(tmp_path, capsys):
    sc = ct.scenario(TRUTH, ref_point=REF)
    rec = ct.write_recording(_gnss_late(ct.record(sc)), tmp_path / "r.csv")
    geo = ct.write_geometry(tmp_path / "g.yaml")
    out, js = tmp_path / "p.yaml", tmp_path / "r.json"
    assert (
        cli.main(
            ["identify", str(rec), "--vehicle", str(geo), "--out", str(out), "--json", str(js)]
        )
        == 0
    )
    printed = capsys.readouterr().out
    sel = json.loads(js.read_text())["longitudinal"]["selection"]
    assert sel["chosen"] != "gps_speed"
    assert set(sel["scores"]) == {"wheel_speeds", "gps_speed", "accel_x"}
    p = load_params(out)
    assert p.accel_source_chosen == sel["chosen"]
    assert set(p.accel_source_scores_mps2) == set(sel["scores"])
    assert f"acceleration source: {sel['chosen']}" in printed
    assert "gps_speed" in printed
