"""The CasADi NMPC (controller/nmpc.py) checks the OSQP fast path on the same problem."""
from __future__ import annotations

import numpy as np
import pytest

from hmpc.controller.closed_loop import run_closed_loop
from hmpc.controller.mpc import MpcController
from hmpc.controller.nmpc import NmpcController
from hmpc.models.params import load_params
from hmpc.models.sim.scenarios import Reference


@pytest.fixture(scope="module")
def params():
    return load_params("params/report_2008.yaml", require_model=True)


def _gentle_curve(seconds=6.0):
    """Speed 3 -> 4.5 m/s in the low zone along a gentle left curve."""
    t = np.arange(0.0, seconds, 0.02)
    v = np.clip(3.0 + 0.5 * (t - 1.0), 3.0, 4.5)
    kap = np.where(t > 1.0, 0.03, 0.0)
    th = np.concatenate([[0.0], np.cumsum(v[1:] * kap[1:] * 0.02)])
    x = np.concatenate([[0.0], np.cumsum(v[1:] * np.cos(th[1:]) * 0.02)])
    y = np.concatenate([[0.0], np.cumsum(v[1:] * np.sin(th[1:]) * 0.02)])
    return Reference(t, x, y, th, v, name="gentle_curve")


def test_nmpc_and_mpc_agree_on_a_simple_case(params):
    ref = _gentle_curve()
    x0 = ref.initial_state(params) + np.array([0.0, 0.3, 0.0, 0.0])  # start 0.3 m off the path
    a = run_closed_loop(MpcController(params), ref, params, initial_state=x0)
    b = run_closed_loop(NmpcController(params), ref, params, initial_state=x0)
    ra, rb = a.recording, b.recording
    dv = np.abs(ra["speed"] - rb["speed"]).max()
    dlat = np.abs(a.lateral_error_m - b.lateral_error_m).max()
    late = ra["time"] >= 1.0  # after the first second (the cold starts differ most)
    dsw = np.abs(ra["steering_cmd"] - rb["steering_cmd"])[late].max()
    dap = np.abs(ra["accel_pedal_cmd"] - rb["accel_pedal_cmd"])[late].max()
    print(f"\nMPC vs NMPC: max |dv| {dv:.4f} m/s, max |d lateral| {dlat:.4f} m, after 1 s max "
          f"|d sw| {dsw:.4f} rad, |d accel pedal| {dap:.4f}; NMPC solve p50 {b.metrics['solve_time_ms']['p50']:.1f} ms, MPC "
          f"{a.metrics['solve_time_ms']['p50']:.2f} ms")
    assert a.metrics["failures"] == 0 and b.metrics["failures"] == 0
    assert a.metrics["internal_errors"] == 0 and b.metrics["internal_errors"] == 0
    assert dv < 0.03
    assert dlat < 0.05
    assert dsw < 0.15
    assert dap < 0.02
    # both correct the initial 0.3 m offset
    assert abs(a.lateral_error_m[-1]) < 0.05 and abs(b.lateral_error_m[-1]) < 0.05


def test_nmpc_failure_is_a_status_and_a_safe_command(params):
    ref = _gentle_curve()
    ctl = NmpcController(params, ipopt_max_iter=1)
    r = ctl.step(ref.initial_state(params), ref, 0.0)
    assert not r.ok and r.status.startswith("controlled_stop")
    assert r.reason.startswith("ipopt")
    assert r.command.accel_pedal == 0.0 and r.command.brake_pedal > 0.0
