"""Real data, end to end: the comma2k19 RAV4 minute (raw CAN + nav + IMU) and the VerifiedCAN
RAV4 drive (raw CAN only, no GNSS). Properties, not hard-coded results: finite figures,
intervals that hold their estimates, honest identifiability verdicts, NMSE% reported."""
import math

import pytest

from hmpc.models.identify.pipeline import identify
from hmpc.models.logs.ingest import ingest_files
from hmpc.models.params import load_params
from hmpc.tools.datafiles import PARAMS_DIR, bundled


@pytest.fixture(scope="module")
def comma():
    ing = ingest_files(bundled("rav4-comma2k19/can.log.gz"), bundled("dbc/toyota_rav4_2017.dbc.gz"),
                       PARAMS_DIR / "toyota_rav4_2017.signals.yaml",
                       nav_path=bundled("rav4-comma2k19/nav.csv.gz"),
                       imu_path=bundled("rav4-comma2k19/imu.csv.gz"))
    vehicle = load_params(PARAMS_DIR / "toyota_rav4_2017.yaml").vehicle
    return identify(ing.recording, vehicle)


@pytest.fixture(scope="module")
def vcan():
    ing = ingest_files(bundled("rav4-2019-verifiedcan/drive.csv.gz"),
                       bundled("dbc/toyota_rav4_2019_tss2.dbc.gz"),
                       PARAMS_DIR / "toyota_rav4_2019.signals.yaml")
    vehicle = load_params(PARAMS_DIR / "toyota_rav4_2019.yaml").vehicle
    return identify(ing.recording, vehicle)


def _finite(*xs):
    return all(x is not None and math.isfinite(x) for x in xs)


def test_comma_minute_steering_gain_with_interval_and_honest_verdict(comma):
    st = comma.params.steering
    rep = comma.report["steering"]
    print(f"comma steering [{st.method}]: scale {st.scale:.4f} [{st.scale_ci95[0]:.4f}, "
          f"{st.scale_ci95[1]:.4f}], offset {st.offset_rad:+.5f} [{st.offset_ci95_rad[0]:+.5f}, "
          f"{st.offset_ci95_rad[1]:+.5f}] rad, dead time {st.dead_time_s:.3f} s\n  {st.note}")
    assert _finite(st.scale, st.offset_rad, *st.scale_ci95, *st.offset_ci95_rad)
    assert st.scale_ci95[0] <= st.scale <= st.scale_ci95[1]
    assert st.offset_ci95_rad[0] <= st.offset_rad <= st.offset_ci95_rad[1]
    assert st.scale > 0  # left steering turns left
    # a highway minute with a few degrees of steering cannot separate offset from scale
    assert st.identifiable is False
    assert "steering-wheel range" in st.note
    checks = {c["name"]: c["passed"] for c in rep["identifiability"]["checks"]}
    assert checks["steering_range_rad"] is False
    assert checks["kinematic_speed_s"] is False  # all above 10 m/s: understeer folded in
    # all three estimates were made and reported, with the agreement of (a) and (b)
    assert set(rep["fits"]) == {"wheel_speed_difference", "yaw_rate", "position_replay"}
    assert rep["agreement_a_b"] is not None
    assert _finite(rep["agreement_a_b"]["rms_difference_rad"])
    assert -0.2 <= st.dead_time_s <= 1.0


def test_comma_minute_high_zone_model_with_nmse(comma):
    zones = {z.name: z for z in comma.params.zones}
    high = zones["high"]
    print(f"comma high zone: a = {high.offset_mps2:+.3f} + {high.scale_mps2:.3f} accel - "
          f"{high.brake_scale_mps2:.3f} brake, NMSE {high.nmse_pct:.1f}%, speed RMSE "
          f"{high.speed_rmse_mps:.3f} m/s; {high.note}")
    assert high.samples > 1000
    assert _finite(high.offset_mps2, high.scale_mps2, high.nmse_pct, high.speed_rmse_mps)
    assert 0.0 < high.nmse_pct <= 100.0 + 1e-6
    assert high.scale_ci95_mps2[0] <= high.scale_mps2 <= high.scale_ci95_mps2[1]
    # the brake switch never closes in this minute: its term is not identified, and says so
    assert "brake" in high.note
    # no data below 5 m/s: the idle and low zones are flagged, not invented silently
    for name in ("idle", "low"):
        assert zones[name].identifiable is False and "no usable data" in zones[name].note
    lon = comma.report["longitudinal"]
    assert "wheel speeds" in lon["accel_source"]
    assert lon["above_last_zone"]["samples"] == 0  # max 19.9 m/s in this minute


def test_verifiedcan_drive_reports_all_three_zones_with_nmse(vcan):
    lon = vcan.report["longitudinal"]
    for z in vcan.params.zones:
        print(f"verifiedcan {z.name}: a = {z.offset_mps2:+.3f} + {z.scale_mps2:.3f} accel - "
              f"{z.brake_scale_mps2:.3f} brake, NMSE {z.nmse_pct}%, speed RMSE "
              f"{z.speed_rmse_mps} m/s, {int(z.samples)} samples; {z.note}")
        assert z.samples > 0, z.name
        assert _finite(z.nmse_pct, z.speed_rmse_mps), z.name
        assert 0.0 < z.nmse_pct <= 100.0 + 1e-6, z.name
        if z.offset_ci95_mps2 is not None:
            assert z.offset_ci95_mps2[0] <= z.offset_mps2 <= z.offset_ci95_mps2[1]
    # no GNSS: acceleration from the car's own wheel speeds, and the source is named
    assert "CAN" in lon["accel_source"] and "wheel speeds" in lon["accel_source"]
    assert lon["standstill"]["seconds"] > 5.0  # stop-and-go: standing time excluded, reported
    # steering still runs (wheel speeds + CAN yaw rate), without position refinement
    st = vcan.params.steering
    assert st.method in ("yaw_rate", "wheel_speed_difference")
    assert "position_replay" not in vcan.report["steering"]["fits"]
    assert st.scale_ci95[0] <= st.scale <= st.scale_ci95[1]
    # FOS shows what the pedals cannot: in ACC driving the acceleration request explains more
    for zr in lon["zones"]:
        assert "accel_cmd" in zr["fos"]["terms"], zr["name"]
