"""Each injectable fault ends in a controlled stop: detected after the fault, the stop's first
frame within 2 control periods (40 ms at 50 Hz) of the detection, standstill reached, no limit
violated (audited from the candump), and the reason in the run's summary."""

from __future__ import annotations

import pytest

from _drive import drive
from hmpc.controller.actuation.drive import DriveConfig

pytestmark = pytest.mark.realtime

FAULT_AT_S = 1.5
PERIOD_S = DriveConfig().control_period_s

CASES = [
    ("feedback_loss", "feedback_loss"),
    ("clock_freeze", "clock_freeze"),
    ("solver_failure", "solver_failure"),
    ("bus_error", "bus_error"),
    ("driver_override", "driver_override"),
    ("vehicle_rejects", "vehicle_rejects"),
]


@pytest.mark.parametrize("profile", ["toyota", "bywire"])
@pytest.mark.parametrize("fault,reason", CASES)
def test_fault_ends_in_controlled_stop(profile, fault, reason, tmp_path):
    res, _ = drive(profile, "figure8", 8.0, tmp_path, faults=[f"{fault}@{FAULT_AT_S}"])
    s = res.summary
    st = s["stop"]
    print(profile, fault, st, s["node"]["rejected"], s["blocked_at_encoder"], s["limit_audit"])
    assert st["reason"] == reason
    assert FAULT_AT_S <= st["detected_t_s"] < FAULT_AT_S + 0.5
    assert 0.0 <= st["t_s"] - st["detected_t_s"] <= 2 * PERIOD_S + 1e-6
    assert st["standstill_t_s"] is not None and st["standstill_t_s"] > st["t_s"]
    assert s["limit_violations"] == 0
    if fault == "vehicle_rejects":
        assert s["frames_rejected_by_vehicle"] > 0
    else:
        assert s["frames_rejected_by_vehicle"] == 0
