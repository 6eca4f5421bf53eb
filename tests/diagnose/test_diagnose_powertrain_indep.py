"""`hmpc diagnose` on powertrains it was not built on (``tests/indep/powertrain_truth.py``, numpy
only, in its own terms: torques, ratios, forces), 300 s at 50 Hz:

- a five-speed automatic (pedal gain and engine braking scale with the gear's ratio, shifts
  with hysteresis, ``engine_rpm`` recorded): the top finding is ``gears``, the ratios found
  are the truth's, each gear's accelerator gain and engine braking match the truth's, and
  the ``--params-out`` file loads;
- the same car without ``engine_rpm``: gears are named untested, with a note;
- a single-ratio car whose recording lacks the brake: no brake input is claimed (``brake_pedal``
  absent, never filled in), the top finding is ``unobserved_braking``, its windows lie where
  the truth brakes and its levels within the friction bound; with a driver who never brakes
  it is tested and not found;
- a by-wire car following a speed command through a proportional controller whose motor limits
  the acceleration: the model takes the command as input, the top finding is
  ``actuator_saturation`` at the truth's limit; without the limit nothing is named and the
  speed loop's time constant is the truth's.
"""

from __future__ import annotations

import numpy as np
import pytest

from hmpc.models.diagnose.diagnose import diagnose
from hmpc.models.logs.recording import Recording
from hmpc.models.params import parse_params
from hmpc.tools.cmd_diagnose import params_text
from indep import powertrain_truth as pt

VEHICLE = parse_params(pt.geometry()).vehicle


def _diagnose(ch: dict, name: str):
    return diagnose(Recording(ch, meta={"path": name}), VEHICLE)


def _summary(dg):
    return [(f["effect"], round(f["gain"], 3)) for f in dg.findings]


@pytest.fixture(scope="module")
def gearbox():
    sc = pt.gearbox_scenario(seed=0)
    run = pt.simulate(sc)
    return sc, run, _diagnose(pt.record(sc, run), "powertrain gearbox")


def _truth_gain(car: pt.Car, gear: int) -> float:
    """Acceleration per unit pedal in ``gear`` [m/s^2] (the truth's own terms)."""
    return car.torque_max_nm * car.ratio(gear) * car.efficiency / car.wheel_radius_m / car.mass_kg


def test_gearbox_is_named_gears_with_the_truths_ratios_and_gains(gearbox, tmp_path):
    sc, run, dg = gearbox
    assert dg.findings, "nothing found"
    top = dg.findings[0]
    assert top["effect"] == "gears", _summary(dg)
    assert top["gain"] >= 0.5 and top["heldout_rmse_after"] < top["heldout_rmse_before"]
    g = top["gears"]
    car = sc.car
    truth_ratio = [
        60.0 * car.ratio(i) / (2 * np.pi * car.wheel_radius_m) for i in range(len(pt.GEAR_RATIOS))
    ]
    assert len(g["ratios_rpm_per_mps"]) == len(truth_ratio)
    assert np.allclose(g["ratios_rpm_per_mps"], truth_ratio, rtol=0.02)
    # accelerator gain per gear within 10 % of the truth's torque path
    for i, k in enumerate(g["accel_pedal_gain_mps2"]):
        assert k == pytest.approx(_truth_gain(car, i), rel=0.10), (i, k)
    # engine braking per 1000 rpm: the drag torque through the gear, within 10 %
    for i, e in enumerate(g["engine_braking_per_krpm_mps2"]):
        truth = -car.engine_brake_nm_per_krpm * _truth_gain(car, i) / car.torque_max_nm
        assert e == pytest.approx(truth, rel=0.10), (i, e, truth)
    # the gear at each sample: the windows name the truth's gear for most of their time
    t = run.t_s
    agree = total = 0.0
    for t0, t1, gi in g["windows"]:
        m = (t >= t0) & (t <= t1)
        agree += np.sum(run.gear[m] == gi)
        total += m.sum()
    assert total > 0.5 * len(t) * 0.5 and agree / total > 0.95
    assert top["parameters"]["n_gears"] == len(truth_ratio)
    assert not dg.unexplained, dg.unexplained
    text = params_text(dg.params_out, tmp_path / "p.yaml")  # raises if hmpc would refuse it
    assert "gears:" in text


def test_without_engine_rpm_gears_are_named_untested():
    sc = pt.gearbox_scenario(seed=1)
    sc.record_rpm = False
    dg = _diagnose(pt.record(sc), "powertrain no rpm")
    h = next(h for h in dg.hypotheses if h["effect"] == "gears")
    assert h["tested"] is False and "engine_rpm" in h["why"]
    assert any(n.startswith("gear effects could not be tested") for n in dg.notes)
    assert all(f["effect"] != "gears" for f in dg.findings)


@pytest.fixture(scope="module")
def unrecorded_brake():
    sc = pt.unrecorded_brake_scenario(seed=0)
    run = pt.simulate(sc)
    return sc, run, _diagnose(pt.record(sc, run), "powertrain no brake")


def test_unrecorded_brake_is_absent_and_named_unobserved_braking(unrecorded_brake, tmp_path):
    sc, run, dg = unrecorded_brake
    assert dg.longitudinal_input == "accel_pedal"
    assert "brake_pedal" in dg.absent_inputs
    j = dg.to_json()
    assert j["longitudinal_input"] == "accel_pedal" and "brake_pedal" in j["absent_inputs"]
    top = dg.findings[0]
    assert top["effect"] == "unobserved_braking", _summary(dg)
    assert top["gain"] >= 0.3 and top["heldout_rmse_after"] < top["heldout_rmse_before"]
    p = top["parameters"]
    assert 0 < p["max_decel_mps2"] <= p["mu"] * 9.80665
    # each window lies where the truth brakes (or stands held) with the pedal released
    t = run.t_s
    wins = top["braking_windows"]
    assert len(wins) == p["n_windows"] >= 3
    for t0, t1, lv in wins:
        m = (t >= t0) & (t <= t1)
        assert np.mean(run.brake[m] > 0) > 0.8, (t0, t1)
        assert np.all(run.pedal[m] == 0), (t0, t1)
        # its level against the truth's mean braking deceleration there (within 35 %: one
        # level for a braking that varies within the window)
        truth = np.mean(run.brake[m]) * sc.car.brake_force_max_n / sc.car.mass_kg
        assert lv == pytest.approx(truth, rel=0.35), (t0, t1, lv, truth)
    params_text(dg.params_out, tmp_path / "p.yaml")


def test_a_driver_who_never_brakes_gives_no_unobserved_braking():
    """The false alarm the hypothesis must not raise: the same brake-less recording of a car
    whose driver only lifts off (it coasts down): tested, not a finding."""
    sc = pt.unrecorded_brake_scenario(seed=1)
    sc.driver_brakes = False
    dg = _diagnose(pt.record(sc), "powertrain coasting only")
    assert dg.longitudinal_input == "accel_pedal"
    h = next(h for h in dg.hypotheses if h["effect"] == "unobserved_braking")
    assert h["tested"] is not False and not h.get("finding"), h
    assert all(f["effect"] != "unobserved_braking" for f in dg.findings)


@pytest.mark.parametrize("limit", [1.5, 2.5])
def test_speed_command_saturation_is_named_at_the_truths_limit(limit, tmp_path):
    car = pt.ByWireCar(accel_limit_mps2=limit)
    dg = _diagnose(pt.speed_command_record(car, seed=2), f"by-wire {limit}")
    assert dg.longitudinal_input == "speed_cmd"
    assert {"accel_pedal", "brake_pedal"} <= set(dg.absent_inputs)
    top = dg.findings[0]
    assert top["effect"] == "actuator_saturation", _summary(dg)
    assert top["gain"] >= 0.3
    assert top["parameters"]["accel_mps2"] == pytest.approx(limit, rel=0.15)
    params_text(dg.params_out, tmp_path / "p.yaml")


def test_speed_command_without_limit_names_nothing_and_its_time_constant():
    car = pt.ByWireCar(accel_limit_mps2=50.0)
    dg = _diagnose(pt.speed_command_record(car, seed=3), "by-wire unlimited")
    assert all(f["gain"] <= 0.10 for f in dg.findings), _summary(dg)
    resp = dg.channels["speed"]["speed_cmd_response"]
    for z in resp.values():
        assert z["tau_s"] == pytest.approx(1.0 / car.k_p_per_s, rel=0.05)


def test_recorded_gear_channel_is_used_when_engine_rpm_is_absent():
    sc = pt.gearbox_scenario(seed=0)
    sc.record_rpm = False
    run = pt.simulate(sc)
    ch = pt.record(sc, run)
    ch["gear"] = np.array([str(int(g) + 1) for g in run.gear], dtype=object)
    dg = _diagnose(ch, "powertrain gear channel")
    top = dg.findings[0]
    assert top["effect"] == "gears", _summary(dg)
    assert top["gears"]["source"] == "gear channel" and top["gears"]["gears"] == list("12345")
    # without the engine speed the released pedal is one drag level per gear: it still
    # explains most of the baseline's error
    assert top["gain"] >= 0.5
