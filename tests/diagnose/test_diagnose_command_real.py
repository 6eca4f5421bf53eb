"""`hmpc diagnose` on the two bundled command-driven recordings (neither has an accelerator
pedal): the CAT Vehicle (a by-wire Ford Escape following ``/catvehicle/cmd_vel``, its brake
force recorded as ``brake_pedal``) and the F1TENTH FrictionMaps DS5 (a 1:10 car following an
Ackermann speed command).

Run as a user does (``hmpc ingest`` to CSV, then ``hmpc diagnose`` with ``--json``,
``--report`` and ``--params-out``): exit 0, no traceback, the longitudinal model driven by the
speed command (never by an accelerator pedal the recording lacks: it is listed absent), the
parameter file loads, and every finding is checked against an independent sensor or bound
(an unexpected finding fails until it has a check):

- F1TENTH ``sensor_mounting``: the IMU's turn against the angle of the regression of accel_x on
  dv/dt and speed x yaw rate (numpy); the speed command's time constant against a first-order
  lag fitted to the reached speed by simulation (numpy); the source's README says the reached
  speed lags the command (control delay, VESC saturation).
- CAT Vehicle ``sensor_time_offset``: against the lag that best aligns the by-wire speed with
  the GNSS speed (interpolated cross-match, numpy).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from _data import DATA_DIR, PARAMS_DIR
from hmpc.models.logs.recording import read_channels
from hmpc.models.params import load_params
from hmpc.tools import cli

SETS = {
    "catvehicle": (
        DATA_DIR / "catvehicle-bagpy",
        PARAMS_DIR / "catvehicle.topics.yaml",
        PARAMS_DIR / "catvehicle.yaml",
    ),
    "f1tenth": (
        DATA_DIR / "f1tenth-frictionmaps",
        PARAMS_DIR / "f1tenth_frictionmaps.topics.yaml",
        PARAMS_DIR / "f1tenth.yaml",
    ),
}


def _run(which: str, tmp_path, capsys):
    src, topics, geometry = SETS[which]
    if not src.is_dir():
        pytest.skip(f"bundled data absent: {src}")
    csv, js = tmp_path / "c.csv", tmp_path / "c.json"
    rc = cli.main(["ingest", str(src), "--topics", str(topics), "--out", str(csv)])
    out = capsys.readouterr()
    assert rc == 0 and "Traceback" not in out.err, out.err
    rc = cli.main(
        [
            "diagnose",
            str(csv),
            "--vehicle",
            str(geometry),
            "--json",
            str(js),
            "--report",
            str(tmp_path / "rep"),
            "--params-out",
            str(tmp_path / "p.yaml"),
        ]
    )
    out = capsys.readouterr()
    assert rc == 0 and "Traceback" not in out.err, out.err
    load_params(tmp_path / "p.yaml")
    assert (tmp_path / "rep" / "index.html").exists()
    return read_channels(csv), json.loads(js.read_text()), out.out


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    return np.convolve(x, np.ones(n) / n, mode="same")


def _check_mounting(ch, f):
    """accel_x = k (cos psi dv/dt + sin psi v r) + c: psi from a plain least-squares fit."""
    t, v = ch["time"], ch["speed"]
    dt = float(np.median(np.diff(t)))
    vs = _smooth(v, 25)
    a = np.gradient(vs, dt)
    ax = _smooth(ch["accel_x"], 25)
    vr = vs * _smooth(ch["yaw_rate"], 25)
    ok = np.isfinite(a) & np.isfinite(ax) & np.isfinite(vr) & (np.abs(v) > 0.5)
    X = np.column_stack([a[ok], vr[ok], np.ones(ok.sum())])
    c = np.linalg.lstsq(X, ax[ok], rcond=None)[0]
    psi = math.atan2(c[1], c[0])
    assert abs(np.corrcoef(ax[ok], vr[ok])[0, 1]) > abs(np.corrcoef(ax[ok], a[ok])[0, 1])
    est = f["parameters"]["yaw_rad"]
    assert abs(math.degrees(est - psi)) < 10.0, (math.degrees(est), math.degrees(psi))


def _check_clock_offset(ch, f):
    """speed(t) = gps_speed(t - c): the c in [-0.5, 0.5] s that best aligns the two."""
    t, v, g = ch["time"], ch["speed"], ch["gps_speed"]
    ok = np.isfinite(v) & np.isfinite(g) & (v > 0.5)
    tg = t[np.isfinite(g)]
    cs = np.arange(-0.5, 0.5001, 0.01)
    err = [np.mean((v[ok] - np.interp(t[ok] - c, tg, g[np.isfinite(g)])) ** 2) for c in cs]
    c = float(cs[int(np.argmin(err))])
    lo, hi = f["intervals"]["offset_s"]
    assert lo - 0.02 <= c <= hi + 0.02, (c, lo, hi)


CHECKS = {"sensor_mounting": _check_mounting, "sensor_time_offset": _check_clock_offset}


def _first_order_tau(ch) -> float:
    """The time constant of v' = (speed_cmd - v) / tau that best replays the reached speed in
    10-s windows from the measured speed (numpy, on a 0.05-s grid of tau)."""
    t, v, c = ch["time"], ch["speed"], ch["speed_cmd"]
    dt = float(np.median(np.diff(t)))
    ok = np.isfinite(v) & np.isfinite(c)
    L = int(10.0 / dt)
    starts = [i for i in range(0, len(t) - L, L) if ok[i : i + L].all()]
    best = (np.inf, None)
    for tau in np.arange(0.1, 3.0, 0.05):
        e = 0.0
        for i in starts:
            x = v[i]
            for k in range(i, i + L):
                e += (x - v[k]) ** 2
                x += (c[k] - x) / tau * dt
        best = min(best, (e, float(tau)))
    return best[1]


def test_f1tenth_runs_on_its_speed_command_and_each_finding_holds(tmp_path, capsys):
    ch, j, out = _run("f1tenth", tmp_path, capsys)
    assert j["longitudinal_input"] == "speed_cmd"
    assert {"accel_pedal", "brake_pedal"} <= set(j["absent_inputs"])
    assert "accel_pedal" not in out.split("longitudinal input:")[1].splitlines()[0]
    assert j["findings"], "nothing found"
    for f in j["findings"]:
        assert f["effect"] in CHECKS, f"no independent check for {f['effect']}"
        CHECKS[f["effect"]](ch, f)
    # the reached speed lags the command (the source's README): the speed loop's time constant
    # per fitted zone against a first-order lag fitted independently, within a factor of two
    tau = _first_order_tau(ch)
    resp = j["channels"]["speed"]["speed_cmd_response"]
    assert resp and all(
        z["tau_s"] is not None and 0.5 * tau <= z["tau_s"] <= 2.0 * tau for z in resp.values()
    ), (tau, resp)


def test_catvehicle_runs_on_its_speed_command_and_each_finding_holds(tmp_path, capsys):
    ch, j, out = _run("catvehicle", tmp_path, capsys)
    assert j["longitudinal_input"] == "speed_cmd+brake_pedal"
    assert "accel_pedal" in j["absent_inputs"]
    assert j["findings"], "nothing found"
    for f in j["findings"]:
        assert f["effect"] in CHECKS, f"no independent check for {f['effect']}"
        CHECKS[f["effect"]](ch, f)
    assert j["not_diagnosed"]["steering"].startswith("no steering_wheel_angle")
