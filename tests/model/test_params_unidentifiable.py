"""Values identification flagged ``identifiable: false`` are refused by ``hmpc simulate``,
``hmpc drive`` and the controller construction they share, in one line naming the key and the
flag that accepts them (``--accept-unidentifiable``); with the flag they run and warn.
"""

from __future__ import annotations

import pytest
import yaml

from _data import PARAMS_DIR, REPORT_PARAMS
from hmpc.models.errors import ParamError
from hmpc.models.params import load_params
from hmpc.models.unidentifiable import check_identifiable
from hmpc.tools.cli import main
from hmpc.controller.build import make_controller
from hmpc.controller.mpc import MpcController
from hmpc.controller.nmpc import NmpcController
from hmpc.controller.pid import PidController

FLAG = "--accept-unidentifiable"


def _flagged(tmp_path, *, steering: bool = False, zones: tuple[int, ...] = ()):
    """report_2008.yaml with the given parts flagged ``identifiable: false``."""
    data = yaml.safe_load(REPORT_PARAMS.read_text())
    if steering:
        data["steering"].update(
            identifiable=False, note="NOT identifiable: the fits disagree beyond their intervals"
        )
    for i in zones:
        data["longitudinal"]["zones"][i].update(
            identifiable=False, note="NOT identifiable: pedal barely exercised"
        )
    path = tmp_path / "flagged.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _one_line_err(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err  # one line, no traceback
    return err[0]


@pytest.mark.parametrize(
    "steering,zones,keys",
    [
        (True, (), ["steering"]),
        (False, (1,), ["longitudinal.zones[1]"]),
        (True, (0, 2), ["steering", "longitudinal.zones[0]", "longitudinal.zones[2]"]),
    ],
)
def test_simulate_refuses_flagged_values_naming_key_and_flag(
    tmp_path, capsys, steering, zones, keys
):
    f = _flagged(tmp_path, steering=steering, zones=zones)
    rc = main(["simulate", "--params", str(f), "--scenario", "idle_hold"])
    line = _one_line_err(capsys)
    assert rc == 2
    assert str(f) in line and FLAG in line and "identifiable: false" in line
    for k in keys:
        assert k in line, (k, line)
    # a zone that is not flagged is not named
    for i in set(range(3)) - set(zones):
        assert f"zones[{i}]" not in line


def test_an_unflagged_or_true_file_is_not_refused(tmp_path):
    data = yaml.safe_load(REPORT_PARAMS.read_text())
    data["steering"]["identifiable"] = True
    f = tmp_path / "ok.yaml"
    f.write_text(yaml.safe_dump(data))
    assert check_identifiable(load_params(f)) == []
    assert check_identifiable(load_params(REPORT_PARAMS)) == []  # no flag at all: hand-written


def test_simulate_with_the_flag_runs_and_warns_in_one_line(tmp_path, capsys):
    f = _flagged(tmp_path, steering=True, zones=(1,))
    out = tmp_path / "rec.csv"
    rc = main(["simulate", "--experiment", "ramps", "--params", str(f), "--out", str(out), FLAG])
    err = capsys.readouterr().err
    assert rc == 0 and out.is_file()
    warnings = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warnings) == 1, err
    w = warnings[0]
    assert "'steering'" in w and "'longitudinal.zones[1]'" in w and "zones[0]" not in w
    assert FLAG in w and str(f) in w


def test_plant_params_are_checked_too(tmp_path, capsys):
    f = _flagged(tmp_path, zones=(2,))
    rc = main(
        [
            "simulate",
            "--params",
            str(REPORT_PARAMS),
            "--plant-params",
            str(f),
            "--scenario",
            "idle_hold",
        ]
    )
    line = _one_line_err(capsys)
    assert rc == 2 and "longitudinal.zones[2]" in line and FLAG in line


@pytest.mark.parametrize("name", ["mpc", "nmpc", "pid"])
def test_controller_construction_refuses_unless_accepted(tmp_path, name):
    params = load_params(_flagged(tmp_path, steering=True))
    with pytest.raises(ParamError, match=r"key 'steering'.*--accept-unidentifiable"):
        make_controller(name, params)
    ctl = make_controller(name, params, accept_unidentifiable=True)
    assert type(ctl) is {"mpc": MpcController, "nmpc": NmpcController, "pid": PidController}[name]
    assert ctl.params.steering.identifiable is False  # built on the flagged values as given


def test_drive_refuses_flagged_values_before_touching_the_bus(tmp_path, capsys):
    f = _flagged(tmp_path, zones=(0,))
    log = tmp_path / "run.log"
    rc = main(
        [
            "drive",
            "--params",
            str(f),
            "--actuation",
            str(PARAMS_DIR / "bywire.actuation.yaml"),
            "--vehicle-sim",
            "--scenario",
            "figure8",
            "--duration",
            "1",
            "--candump",
            str(log),
        ]
    )
    line = _one_line_err(capsys)
    assert rc == 2 and "longitudinal.zones[0]" in line and FLAG in line and str(f) in line
    assert not log.exists()


@pytest.mark.realtime
def test_drive_with_the_flag_runs_and_warns(tmp_path, capsys):
    f = _flagged(tmp_path, steering=True)
    log = tmp_path / "run.log"
    rc = main(
        [
            "drive",
            "--params",
            str(f),
            "--actuation",
            str(PARAMS_DIR / "bywire.actuation.yaml"),
            "--vehicle-sim",
            "--scenario",
            "figure8",
            "--duration",
            "1",
            "--candump",
            str(log),
            FLAG,
        ]
    )
    err = capsys.readouterr().err
    assert rc == 0, err
    assert log.stat().st_size > 0
    warnings = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warnings) == 1 and "'steering'" in warnings[0] and FLAG in warnings[0]


def test_a_file_identified_from_the_real_comma_minute_is_refused_then_accepted(tmp_path, capsys):
    """End to end on real data: the comma minute's steering (a few degrees of highway
    steering) and zones (brake never pressed, no data below 5 m/s) come out flagged; simulate
    refuses the file naming them, and runs with the flag."""
    from _data import bundled

    d = "rav4-comma2k19/"
    out = tmp_path / "comma.yaml"
    rc = main(
        [
            "identify",
            str(bundled(d + "can.log.gz")),
            "--dbc",
            str(bundled("dbc/toyota_rav4_2017.dbc.gz")),
            "--signals",
            str(PARAMS_DIR / "toyota_rav4_2017.signals.yaml"),
            "--nav",
            str(bundled(d + "nav.csv.gz")),
            "--imu",
            str(bundled(d + "imu.csv.gz")),
            "--vehicle",
            str(PARAMS_DIR / "toyota_rav4_2017.yaml"),
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    capsys.readouterr()
    p = load_params(out, require_model=True)
    flagged = ["steering"] * (p.steering.identifiable is False) + [
        f"longitudinal.zones[{i}]" for i, z in enumerate(p.zones) if z.identifiable is False
    ]
    assert flagged  # measured: steering and all three zones
    rc = main(["simulate", "--params", str(out), "--scenario", "idle_hold"])
    line = _one_line_err(capsys)
    assert rc == 2 and FLAG in line and all(k in line for k in flagged), line
    rc = main(
        [
            "simulate",
            "--experiment",
            "ramps",
            "--params",
            str(out),
            "--out",
            str(tmp_path / "rec.csv"),
            FLAG,
        ]
    )
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    assert rc == 0 and len(warnings) == 1 and all(f"'{k}'" in warnings[0] for k in flagged)
