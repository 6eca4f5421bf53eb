"""An unexplained change in the car on SHORT recordings: one minute is not enough data for a
fixed error reduction to mean a change.

``diagnose`` reports a change no catalogue hypothesis models when the final longitudinal model
fitted before and after a split point explains the data better than one fit. On one minute
of closed-loop ACC driving (``tests/indep/acc_truth.py``: nothing changes in the car) the
residual is one independent sample per 1-5 s, so 13-67 effective samples carry the split's
6-10 parameters, and the best of 13 splits lowered the equation error by 16-73 %: with the
former rule (a reduction of 15 % is a change) 16 of 16 such minutes (flat and hilly, seeds
0-7) reported "mass, load, tyres, a trailer". The split is now an F test in effective samples,
Bonferroni over the splits, on top of that reduction (``unexplained.unexplained_change``):
measured 0 of 40 minutes (five acc_truth cases, seeds 0-7; smallest family-wise p 0.28) and none of
ten 10-minute ones, while a 0.7 x pedal gain from half time (CommonRoad generator,
``gain_factor_second_half``, truth sets A-C, seeds 0-2) is still found on every minute the
former rule found it on (8 of 12, family-wise p <= 1e-6; on the other 4 no split reduces
the error by 15 %) and on every 2 and 10 minutes.

Seeds are fixed (in the test ids); each recording takes a few seconds.
"""

from __future__ import annotations

import dataclasses

import pytest

from hmpc.models.diagnose.common import DiagnoseConfig
from hmpc.models.diagnose.diagnose import diagnose
from hmpc.models.logs.recording import Recording
from hmpc.models.params import parse_params
from indep import acc_truth as at
from indep import commonroad_truth as ct
from indep import diagnose_matrix as dm

DURATION_S = 60.0

#: (dead time [s], grade amplitude [rad], seed): the minutes the former rule flagged with the
#: largest reductions (dead025 seed 6: 65 %; flat seed 3: 31 %) and the one whose raw residual
#: correlation length is shortest (flat seed 6: 16 samples, read as 190 independent samples)
CLEAN = [(0.5, 0.0, 3), (0.5, 0.0, 6), (0.25, 0.03, 0), (0.25, 0.03, 6)]


@pytest.mark.parametrize(
    "dead_s,grade_rad,seed", CLEAN, ids=[f"d{d}-grade{g}-seed{s}" for d, g, s in CLEAN]
)
def test_clean_acc_minute_reports_no_change(dead_s, grade_rad, seed):
    sc = at.scenario(dead_s, 0.0, seed=seed, duration_s=DURATION_S, grade_amp_rad=grade_rad)
    rec = Recording(at.record(sc), meta={"path": f"acc_truth d={dead_s} seed {seed}"})
    dg = diagnose(rec, parse_params(at.geometry()).vehicle)
    assert not dg.unexplained, [(u["windows"], u["why"]) for u in dg.unexplained]


def test_heavier_second_half_is_still_found_on_one_minute():
    """CommonRoad generator, truth set A, seed 1, one minute: throttle and brake gains x 0.7
    from 30 s on (outside the catalogue). Measured: from 30.0 s, 97 % of the equation error
    removed by the split, F = 84 on 6 and 14 effective degrees of freedom, p 5e-9 over 13
    splits."""
    sc = dataclasses.replace(dm.scenario("mass_change", "A", 1), duration_s=DURATION_S)
    t_change = 0.5 * DURATION_S
    rec = Recording(ct.record(sc), meta={"path": "commonroad mass_change A seed 1, 60 s"})
    dg = diagnose(rec, parse_params(ct.geometry()).vehicle)
    assert dg.unexplained, [(f["effect"], round(f["gain"], 3)) for f in dg.findings]
    u = dg.unexplained[0]
    ((t0, t1),) = u["windows"]
    assert abs(t0 - t_change) <= 0.1 * DURATION_S, u["windows"]
    assert t1 > t_change + 0.8 * (DURATION_S - t_change), u["windows"]
    assert u["share_of_error"] > 0.5
    st = u["split_test"]
    assert st["p_family"] <= DiagnoseConfig().change_alpha
    assert u["error_reduction_split"] >= DiagnoseConfig().change_min_reduction
    assert st["dof"][1] < 100  # counted in effective samples, not the 3000 samples
