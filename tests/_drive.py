"""Helpers of the drive tests: one real-time run of the drive loop against the vehicle simulator
node on python-can's virtual bus (a fresh channel per run), audited from its own candump."""

from __future__ import annotations

import itertools
import os

import numpy as np

from _data import PARAMS_DIR, REPORT_PARAMS
from hmpc.controller.actuation.candump import audit_candump
from hmpc.controller.actuation.drive import DriveLoop
from hmpc.controller.actuation.faults import parse_fault
from hmpc.controller.actuation.profiles import load_profile
from hmpc.controller.actuation.vehicle_node import BYWIRE_RATES_HZ, TOYOTA_RATES_HZ, VehicleNode
from hmpc.controller.closed_loop import run_closed_loop
from hmpc.controller.mpc import MpcConfig, MpcController
from hmpc.models.params import load_params
from hmpc.models.reference import Reference
from hmpc.models.sim.scenarios import make_scenario

PROFILES = {
    "toyota": PARAMS_DIR / "toyota_rav4_2017.actuation.yaml",
    "bywire": PARAMS_DIR / "bywire.actuation.yaml",
}
_n = itertools.count()


def params():
    return load_params(REPORT_PARAMS, require_model=True)


#: the Toyota node's ACC powertrain lag [s] (controller/actuation/vehicle_node.py), which the
#: report's model lacks
TOYOTA_ACC_LAG_S = 0.25


def controller_params(profile: str):
    """The MPC's model for a drive: the report's, and for the Toyota profile with the node's
    ACC lag as identify/diagnose reports it (an ``extensions: actuator_lag`` entry)."""
    p = params()
    if profile == "toyota":
        p.extensions = {"actuator_lag": {"longitudinal": {"tau_s": TOYOTA_ACC_LAG_S}}}
    return p


def truncated(ref: Reference, t_end_s: float) -> Reference:
    """The first ``t_end_s`` seconds of a reference."""
    n = int(np.searchsorted(ref.time_s, ref.time_s[0] + t_end_s)) + 1
    return Reference(
        ref.time_s[:n],
        ref.x_m[:n],
        ref.y_m[:n],
        ref.heading_rad[:n],
        ref.speed_mps[:n],
        name=f"{ref.name}[:{t_end_s:g}s]",
    )


def drive(
    profile: str, scenario: str, duration_s: float, tmp_path, faults=(), ref_s: float | None = None
):
    """One real-time run; run once more (a fresh bus and node) only after a host stall:
    a ``deadline_misses`` stop (three consecutive control steps more than a period late), or
    a ``feedback_loss`` stop while the simulator node's own thread went silent for more than
    the stale rule's 3 wheel-speed periods (the node's ``max_gap_s``: the simulated car really
    stopped talking, and the loop was right to stop). Both rules are tested on their own in
    test_actuation_safety.py; a stall on a shared CI machine is not what these tests check.
    A second stall fails the test."""
    res, log = _drive_once(profile, scenario, duration_s, tmp_path, faults, ref_s, 0)
    stall = host_stall(profile, res.summary, faults)
    if stall:
        print(f"host stall: {stall}; run again")
        res, log = _drive_once(profile, scenario, duration_s, tmp_path, faults, ref_s, 1)
    return res, log


def host_stall(profile: str, summary: dict, faults=()) -> str:
    """Why this run's stop was a host stall, or "" (see ``drive``); never when the test
    injected that stop's fault itself."""
    stop = summary["stop"]
    if any(f.split("@")[0] == stop["reason"] for f in faults):
        return ""
    if stop["reason"] == "deadline_misses":
        return f"deadline_misses at t = {stop['t_s']} s"
    if stop["reason"] == "feedback_loss" and summary.get("node"):
        prof = load_profile(PROFILES[profile])
        msg = prof.signal_map.channels["speed"].message
        period = 1.0 / (TOYOTA_RATES_HZ if profile == "toyota" else BYWIRE_RATES_HZ)[msg]
        gap = summary["node"]["max_gap_s"].get(msg, 0.0)
        if gap > 3.0 * period:
            return (
                f"feedback_loss at t = {stop['t_s']} s: the node's thread did not publish "
                f"{msg} for {gap * 1e3:.0f} ms (period {period * 1e3:.0f} ms)"
            )
    return ""


def _drive_once(profile, scenario, duration_s, tmp_path, faults, ref_s, attempt):
    p = params()
    prof = load_profile(PROFILES[profile])
    ref = make_scenario(scenario, p)
    if ref_s is not None:
        ref = truncated(ref, ref_s)
    kw = {"interface": "virtual", "channel": f"hmpc-test-{os.getpid()}-{next(_n)}"}
    node = VehicleNode(prof, p, kw, start_state=ref.initial_state(p))
    log = tmp_path / f"{profile}-{scenario}-{attempt}.log"
    loop = DriveLoop(
        prof,
        p,
        MpcController(controller_params(profile), MpcConfig()),
        ref,
        kw,
        log,
        duration_s=duration_s,
        faults=[parse_fault(f) for f in faults],
        node=node,
    )
    res = loop.run()
    audit = audit_candump(prof, p, log)
    res.summary["limit_violations"] = audit["limit_violations"]
    res.summary["limit_audit"] = audit
    return res, log


def simulate_baseline(scenario: str, t_end_s: float) -> dict:
    """``hmpc simulate``'s closed loop on the same stretch of reference, at the drive loop's
    50 Hz, with simulate's default sensors and estimator (the figures the drive tests compare
    with; the node adds CAN quantisation and the drive loop dead-reckons from CAN)."""
    p = params()
    ref = truncated(make_scenario(scenario, p), t_end_s)
    res = run_closed_loop(MpcController(p, MpcConfig()), ref, p, control_period_s=0.02)
    return res.metrics
