"""`hmpc diagnose --report DIR`: the HTML report opens in headless Chromium, a screenshot is
rendered, and the page holds its figures (residual maps over time and regime, before/after)."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from hmpc.models.diagnose.testdata import make_case
from hmpc.tools import cli
from hmpc.tools.datafiles import PARAMS_DIR

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    rec, _ = make_case("aero_drag", seed=1)
    rec.to_csv(d / "rec.csv")
    rc = cli.main(
        [
            "diagnose",
            str(d / "rec.csv"),
            "--vehicle",
            str(PARAMS_DIR / "report_2008.yaml"),
            "--report",
            str(d / "html"),
        ]
    )
    assert rc == 0
    return d / "html"


def test_report_has_findings_equations_and_figures(report_dir):
    html = (report_dir / "index.html").read_text()
    assert "aero_drag" in html and "dv/dt = eq. 8 - c * v^2" in html
    assert "95 % interval" in html and "Held-out speed RMSE" in html
    imgs = re.findall(r'<img src="([^"]+)"', html)
    assert any(i.startswith("residual_time_speed") for i in imgs)
    assert any(i.startswith("residual_regime_speed") for i in imgs)
    for i in imgs:
        assert (report_dir / i).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.skipif(
    CHROMIUM is None,
    reason="no chromium on this machine (apt-get install chromium); the HTML test above still runs",
)
def test_report_renders_in_headless_chromium(report_dir, tmp_path):
    from matplotlib.image import imread

    shot = tmp_path / "shot.png"
    url = (report_dir / "index.html").resolve().as_uri()
    base = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        f"--user-data-dir={tmp_path / 'profile'}",
    ]
    subprocess.run(
        base + ["--window-size=1200,2000", f"--screenshot={shot}", url],
        check=True,
        capture_output=True,
        timeout=120,
    )
    img = imread(shot)
    assert img.shape[0] >= 1000 and img.shape[1] >= 1000
    assert float(np.std(img[..., :3])) > 0.05  # not a blank page
    # the page Chromium built holds the figures, and each one it refers to exists
    dom = subprocess.run(
        base + ["--dump-dom", "--virtual-time-budget=5000", url],
        check=True,
        capture_output=True,
        timeout=120,
        text=True,
    ).stdout
    srcs = re.findall(r'<img src="([^"]+)"', dom)
    assert len(srcs) >= 4, dom[:500]
    assert all((report_dir / s).exists() for s in srcs)


def test_report_names_units_times_and_what_each_figure_compares(report_dir):
    html = (report_dir / "index.html").read_text()
    # the hypotheses table has a unit column, and each tested row's unit is its channel's
    table = html.split("All hypotheses tested", 1)[1]
    assert "<th>unit</th>" in table
    rows = re.findall(
        r"<tr><td>([^<]+)</td><td>([^<]+)</td><td>([^<]+)</td><td>([^<]+)</td>", table
    )
    # angles are shown to people in degrees (the JSON keeps radians)
    units = {
        "speed": "m/s",
        "heading": "deg",
        "accel": "m/s^2",
        "position": "m",
        "speed_vs_gnss": "m/s",
        "road_wheel_angle": "deg",
        "accel_vs_speed": "m/s^2",
        "yaw_rate_vs_wheels": "deg/s",
    }
    tested = [r for r in rows if r[2] != "-"]
    assert tested and all(r[3] == units[r[2]] for r in tested), rows
    # the page says which clock its times are in
    text = " ".join(re.sub(r"<[^>]+>", "", html).split())
    assert "seconds since the start of the recording" in text and "epoch seconds" in text
    # "before and after" only for channels a finding changes
    titles = re.findall(r"<h3>([^<]*over time[^<]*)</h3>", html)
    assert any("before and after" in t for t in titles)
    for t in titles:
        if t.startswith("speed free-run"):  # the aero_drag finding is on the speed channel
            assert "before and after" in t
        else:
            assert "baseline only" in t, t
