"""What `hmpc identify` shows a person: the answer first (eq. 7 and eq. 8 per zone, with
intervals and identifiable flags, angles in deg), then what was not identified, then the
evidence; --help says which channels each part needs; figures leave out what the recording
lacks and stay readable on a long straight; nothing is claimed about understeer on a
recording that does not excite it.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from hmpc.models.identify.pipeline import identify
from hmpc.models.logs.recording import Recording
from hmpc.models.params import Vehicle, load_params
from hmpc.models.report.identification import replay_figure, steering_figure
from hmpc.models.sim.sensors import wheel_speeds
from hmpc.models.sim.simulator import simulate_experiment
from hmpc.tools import cli
from _data import REPORT_PARAMS

VEHICLE = Vehicle(wheelbase_m=2.65, track_front_m=1.6)


def straight_line(seed: int = 2) -> Recording:
    """28 s of a straight highway at 20 m/s, 50 Hz: the steering wheel wanders +-2 deg (lane
    keeping), positions and heading integrated from the kinematic bicycle (560 m east, a metre
    or two north), eq. 7 with offset 0.01 rad and scale 0.06."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 28.0, 0.02)
    v = np.full(len(t), 20.0)
    sw = np.radians(2.0) * np.sin(2 * np.pi * 0.07 * t) - 0.01 / 0.06
    delta = 0.01 + 0.06 * sw
    yaw = v * np.sin(delta) / VEHICLE.wheelbase_m
    heading = np.cumsum(yaw) * 0.02
    x = np.cumsum(v * np.cos(heading)) * 0.02
    y = np.cumsum(v * np.sin(heading)) * 0.02
    fl, fr, rl, rr = wheel_speeds(v, delta, 2.65, 1.6, 1.6)
    return Recording(
        {
            "time": t,
            "steering_wheel_angle": sw,
            "wheel_speed_fl": fl,
            "wheel_speed_fr": fr,
            "wheel_speed_rl": rl,
            "wheel_speed_rr": rr,
            "yaw_rate": yaw + rng.normal(0, 0.001, len(t)),
            "x": x,
            "y": y,
            "heading": heading,
            "speed": 0.5 * (rl + rr),
        },
        {},
        {"path": "straight.csv"},
    )


@pytest.fixture(scope="module")
def straight():
    return identify(straight_line(), VEHICLE)


def test_on_a_straight_line_understeer_is_not_testable(straight):
    """28 s of a straight: the lateral acceleration stays below 0.1 m/s^2, so nothing can be
    said about understeer, least of all that it is separable."""
    us = straight.report["steering"]["understeer"]
    assert us["testable"] is False and "not testable" in us["note"]
    assert us["lat_accel_p97_5_mps2"] < 0.5
    assert "separable" not in straight.steering.note


def test_the_arcs_do_excite_understeer():
    res = identify(simulate_experiment("arcs", load_params(REPORT_PARAMS), seed=3), VEHICLE)
    assert res.report["steering"]["understeer"]["testable"] is True


def test_the_path_of_a_long_straight_is_not_a_sliver(straight):
    fig = replay_figure(straight)
    path = fig.axes[0]
    assert path.get_aspect() == "auto" and "NOT to scale" in path.get_title()


def test_figures_leave_out_the_panels_of_absent_channels(straight):
    assert len(steering_figure(straight).axes) == 5  # every channel: all panels
    rec = straight_line()
    for k in ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"):
        del rec.channels[k]
    fig = steering_figure(identify(rec, VEHICLE))
    titles = [a.get_title() for a in fig.axes]
    assert len(fig.axes) == 2, titles  # steering-wheel angle, and the yaw-rate angle vs model
    assert not any("wheel speed" in t for t in titles)
    for a in fig.axes:
        assert any(np.isfinite(np.asarray(ln.get_ydata(), float)).any() for ln in a.lines)
    assert " deg " in fig._suptitle.get_text() and " rad " not in fig._suptitle.get_text()


def test_help_says_what_a_recording_must_hold(capsys):
    with pytest.raises(SystemExit) as ei:
        cli.main(["identify", "--help"])
    out = capsys.readouterr().out
    assert ei.value.code == 0
    assert "docs/conventions.md" in out
    for ch in (
        "steering_wheel_angle",
        "wheel_speed_fl",
        "yaw_rate",
        "accel_pedal",
        "brake_pedal",
        "x, y, heading",
        "--steering-threshold",
    ):
        assert ch in out, ch


def test_the_terminal_leads_with_the_model(tmp_path, capsys):
    rec = tmp_path / "arcs.csv"
    simulate_experiment("arcs", load_params(REPORT_PARAMS), seed=3).save(rec)
    geo = tmp_path / "g.yaml"
    geo.write_text(yaml.safe_dump({"vehicle": {"wheelbase_m": 2.65, "track_front_m": 1.6}}))
    rc = cli.main(["identify", str(rec), "--vehicle", str(geo), "--out", str(tmp_path / "p.yaml")])
    lines = capsys.readouterr().out.splitlines()
    assert rc == 0
    assert lines[0].startswith("steering (eq. 7): road-wheel angle = ") and " deg + " in lines[0]
    assert lines[0].endswith("identifiable")
    zone_lines = [ln for ln in lines if "* accel_pedal - " in ln]
    assert len(zone_lines) == 3 and all(
        ln.strip().startswith(n) for ln, n in zip(zone_lines, ("idle", "low", "high"))
    )
    assert all("* brake_pedal [m/s^2]" in ln for ln in zone_lines)
    first_ni = next(i for i, ln in enumerate(lines) if ln.startswith("not identified:"))
    evidence = lines.index("evidence:")
    assert lines.index(zone_lines[-1]) < first_ni < evidence
    assert " rad" not in "\n".join(lines[:evidence])  # angles for people in deg
