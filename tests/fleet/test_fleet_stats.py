"""The fleet report's statistics and the manifest: pooling against an independent
DerSimonian-Laird computation, drift found where it was planted and not where there is none
(seeded false-alarm rates), and bad manifests refused in one line naming the file and line."""

import math

import numpy as np
import pytest

from hmpc.models.errors import InputError
from hmpc.models.fleet.manifest import read_manifest
from hmpc.models.fleet.stats import DRIFT_ALPHA, Z95, drift, pool, se_from_ci
from hmpc.tools import cli


def _dl_reference(y, se):
    """DerSimonian and Laird (1986), written out term by term as the paper gives it."""
    k = len(y)
    w = [1 / s**2 for s in se]
    sw = sum(w)
    ybar = sum(wi * yi for wi, yi in zip(w, y)) / sw
    q = sum(wi * (yi - ybar) ** 2 for wi, yi in zip(w, y))
    tau2 = max(0.0, (q - (k - 1)) / (sw - sum(wi * wi for wi in w) / sw))
    ws = [1 / (s**2 + tau2) for s in se]
    m = sum(wi * yi for wi, yi in zip(ws, y)) / sum(ws)
    return m, 1 / math.sqrt(sum(ws)), tau2


def test_pool_is_dersimonian_laird_and_widens_when_drives_disagree():
    y, se = [1.00, 1.30, 0.90, 1.10, 1.45], [0.05, 0.08, 0.04, 0.10, 0.06]
    m, ci, tau2 = pool(y, se)
    m_ref, se_ref, tau2_ref = _dl_reference(y, se)
    assert m == pytest.approx(m_ref, rel=1e-12) and tau2 == pytest.approx(tau2_ref, rel=1e-12)
    assert ci[1] - ci[0] == pytest.approx(2 * Z95 * se_ref, rel=1e-12)
    assert tau2 > 0  # these drives disagree beyond their intervals
    # fixed-effect interval would be narrower: the between-drive term widened it
    fixed_se = 1 / math.sqrt(sum(1 / s**2 for s in se))
    assert (ci[1] - ci[0]) / 2 > Z95 * fixed_se * 1.5
    # agreeing drives: tau^2 = 0 and the plain inverse-variance mean
    m2, ci2, t2 = pool([2.0, 2.0, 2.0], [0.1, 0.2, 0.1])
    assert t2 == 0 and m2 == pytest.approx(2.0) and ci2[0] < 2.0 < ci2[1]
    # no interval anywhere: the mean, no interval
    assert pool([1.0, 3.0], [math.nan, math.nan])[:2] == (2.0, None)
    assert math.isnan(se_from_ci(1.0, 1.0)) and se_from_ci(-Z95, Z95) == pytest.approx(1.0)


def _fleets(seed, n_fleets, n_drives, tau_factor):
    rng = np.random.default_rng(seed)
    for _ in range(n_fleets):
        se = rng.uniform(0.5, 2.0, n_drives)
        tau = tau_factor * float(np.median(se))
        yield 5.0 + rng.normal(0.0, se) + rng.normal(0.0, tau, n_drives), se


@pytest.mark.parametrize("n_drives", [6, 12])
def test_no_drift_is_found_where_there_is_none(n_drives):
    """Seeded fleets without a change: drives drawn within their intervals (calibrated),
    and drives that disagree beyond them by as much as one interval (tau = the median
    standard error). The drift scan's design rate DRIFT_ALPHA (1 %) holds for calibrated
    intervals; drives that disagree beyond their intervals raise it (the tau^2 of a few
    drives is uncertain). Measured on these seeds (400 fleets each): 6 drives 1.0 % calibrated,
    5.3 % with the spread; 12 drives 0.25 % and 3.0 %. Bounds: 2 % (DRIFT_ALPHA plus two
    binomial standard errors of 400 fleets, 0.5 % each) and 8 %."""
    n = 400
    calibrated = sum(drift(y, se) is not None for y, se in _fleets(7, n, n_drives, 0.0)) / n
    spread = sum(drift(y, se) is not None for y, se in _fleets(8, n, n_drives, 1.0)) / n
    assert calibrated <= DRIFT_ALPHA + 2 * math.sqrt(DRIFT_ALPHA * (1 - DRIFT_ALPHA) / n)
    assert spread <= 0.08


def test_a_step_is_found_at_its_drive_with_its_levels_and_a_trend_as_a_trend():
    rng = np.random.default_rng(3)
    se = np.full(12, 0.01)
    level = np.where(np.arange(12) >= 3, 2.4, 3.0)
    d = drift(level + rng.normal(0, se), se)
    assert d is not None and d.kind == "step" and d.index == 3
    assert d.after / d.before == pytest.approx(0.8, abs=0.01)
    ramp = 3.0 - 0.05 * np.maximum(0, np.arange(12) - 5)
    d = drift(ramp + rng.normal(0, se), se)
    assert d is not None and d.kind == "trend" and d.index == 6
    assert d.before == pytest.approx(3.0, abs=0.02) and d.after == pytest.approx(2.7, abs=0.02)
    # too few drives to say: none
    assert drift([1.0, 2.0, 3.0], [0.01] * 3) is None


def _manifest(tmp_path, text):
    p = tmp_path / "m.csv"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "text, needle",
    [
        ("vehicle_id,drive_id,start_time,geometry,recording,colour\n", "line 1: unknown column"),
        ("vehicle_id,drive_id,geometry,recording\n", "line 1: missing column(s) start_time"),
        (
            "vehicle_id,drive_id,start_time,geometry,recording\n"
            "A,A1,2026-01-05T08:00:00Z,g.yaml,r.csv\nA,A1,2026-01-06T08:00:00Z,g.yaml,r2.csv\n",
            "line 3: drive_id 'A1' repeats line 2",
        ),
        (
            "vehicle_id,drive_id,start_time,geometry,recording\nA,A1,yesterday,g.yaml,r.csv\n",
            "line 2: start_time 'yesterday' is not ISO 8601",
        ),
        (
            "vehicle_id,drive_id,start_time,geometry,recording,log,dbc,signals\n"
            "A,A1,2026-01-05T08:00:00Z,g.yaml,,can.log,,s.yaml\n",
            "the raw log lacks dbc",
        ),
        (
            "vehicle_id,drive_id,start_time,geometry,recording\nA/..,A1,2026-01-05T08:00:00Z,g,r\n",
            "vehicle_id 'A/..' must be letters",
        ),
    ],
)
def test_a_bad_manifest_is_refused_naming_file_and_line(tmp_path, capsys, text, needle):
    m = _manifest(tmp_path, text)
    with pytest.raises(InputError) as e:
        read_manifest(m)
    assert needle in e.value.one_line() and str(m) in e.value.one_line()
    rc = cli.main(["fleet", "run", str(m), "--out", str(tmp_path / "store")])
    err = capsys.readouterr().err
    assert rc == 2 and needle in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_manifest_paths_are_relative_to_its_folder_and_times_utc(tmp_path):
    m = _manifest(
        tmp_path,
        "vehicle_id,drive_id,start_time,geometry,recording\n"
        "A,A1,2026-01-05T09:00:00+01:00,g.yaml,sub/r.parquet\n",
    )
    (d,) = read_manifest(m)
    assert d.start_time == "2026-01-05T08:00:00Z"
    assert d.files["recording"] == str((tmp_path / "sub" / "r.parquet").resolve())
    assert d.model == "g" and not d.raw


def test_vehicles_of_one_model_compared_and_the_one_that_differs_named():
    from hmpc.models.fleet.report import _compare

    def veh(value, half_width):
        return {
            "parameters": {
                "steering.scale": {
                    "pooled": value,
                    "ci95": [value - half_width, value + half_width],
                    "drift": None,
                }
            }
        }

    vehicles = {
        "V1": veh(0.0800, 0.0002),
        "V2": veh(0.0801, 0.0002),
        "V3": veh(0.0799, 0.0002),
        "V4": veh(0.0850, 0.0002),
    }
    out = _compare(sorted(vehicles), vehicles)["steering.scale"]
    assert out["differs"] == ["V4"]
    assert set(out["vehicles"]) == set(vehicles) and out["between_vehicle_sd"] > 0.001
    # the same vehicles without V4 agree: none named, no spread between them
    del vehicles["V4"]
    out = _compare(sorted(vehicles), vehicles)["steering.scale"]
    assert out["differs"] == [] and out["pooled"] == pytest.approx(0.0800, abs=1e-4)


def test_a_finished_drive_is_skipped_only_for_the_same_inputs_version_and_steps():
    from hmpc.models.fleet.store import finished

    status = {
        "exit": 0,
        "inputs_sha256": "abc",
        "hmpc_version": "1.0",
        "steps": ["ingest", "identify"],
    }
    assert finished(status, "abc", "1.0", ("identify",))
    assert finished(status, "abc", "1.0", ("ingest", "identify"))
    assert not finished(status, "abc", "1.0", ("ingest", "identify", "diagnose"))
    assert not finished(status, "abd", "1.0", ("identify",))  # an input changed
    assert not finished(status, "abc", "1.1", ("identify",))  # another hmpc
    assert not finished({**status, "exit": 2}, "abc", "1.0", ("identify",))  # it failed
    assert not finished(None, "abc", "1.0", ("identify",))  # never run
