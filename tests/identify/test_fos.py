"""Fast Orthogonal Search (models.identify.fos): finds the true terms among distractors, and its
coefficients are ordinary least squares on the terms it selected."""

import numpy as np
import pytest

from hmpc.models.identify.fos import block_holdout, fos

SEED = 20240611


def _system(seed, n=4000, noise=0.1):
    """y = 0.7 + 2 p3 - 1.5 p7 + 0.4 p3*p5 among 14 candidates, one a near-copy of a true term."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(n, 10))
    names = ["1"] + [f"p{i}" for i in range(1, 10)] + ["p3*p5", "p7^2", "p3_alias", "p1*p2"]
    P = np.column_stack(
        [
            np.ones(n),
            base[:, 1:],
            base[:, 3] * base[:, 5],
            base[:, 7] ** 2,
            0.8 * base[:, 3] + 0.6 * base[:, 9] + 0.05 * rng.normal(size=n),
            base[:, 1] * base[:, 2],
        ]
    )
    y = 0.7 + 2.0 * P[:, 3] - 1.5 * P[:, 7] + 0.4 * P[:, names.index("p3*p5")]
    y = y + noise * rng.normal(size=n)
    return P, y, names


@pytest.mark.parametrize("seed", [SEED, SEED + 1, SEED + 2])
def test_fos_recovers_the_true_term_set_among_distractors(seed):
    P, y, names = _system(seed)
    res = fos(P, y, names, force=["1"])
    print(f"seed {seed}: selected {res.terms}, stop: {res.stop_reason}")
    assert set(res.terms) == {"1", "p3", "p7", "p3*p5"}
    coef = dict(zip(res.terms, res.coefficients))
    assert coef["1"] == pytest.approx(0.7, abs=0.02)
    assert coef["p3"] == pytest.approx(2.0, abs=0.02)
    assert coef["p7"] == pytest.approx(-1.5, abs=0.02)
    assert coef["p3*p5"] == pytest.approx(0.4, abs=0.02)
    # the held-out MSE path was what stopped it: it did not fall after the true terms
    assert len(res.holdout_mse_path) == len(res.tried) + 1
    assert res.holdout_mse_path[len(res.terms)] <= res.holdout_mse_path.min() + 1e-12


def test_fos_coefficients_equal_least_squares_on_the_selected_terms():
    P, y, names = _system(SEED)
    res = fos(P, y, names, force=["1"])
    tm = res.train_mask
    assert 0 < (~tm).sum() < len(y)  # a real hold-out was used
    ref, *_ = np.linalg.lstsq(P[tm][:, res.indices], y[tm], rcond=None)
    np.testing.assert_allclose(res.coefficients, ref, rtol=1e-9, atol=1e-12)
    # without a hold-out, a fixed number of terms: OLS on all samples
    res2 = fos(P, y, names, holdout=None, max_terms=6, min_reduction=0.0, noise_threshold=False)
    assert len(res2.terms) == 6
    ref2, *_ = np.linalg.lstsq(P[:, res2.indices], y, rcond=None)
    np.testing.assert_allclose(res2.coefficients, ref2, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res2.predict(P), P[:, res2.indices] @ ref2, atol=1e-9)


def test_error_reductions_account_for_the_training_mse():
    P, y, names = _system(SEED, noise=0.3)
    res = fos(P, y, names, holdout=None, max_terms=5, min_reduction=0.0, noise_threshold=False)
    y2 = float(np.mean(y**2))
    path = res.train_mse_path
    assert path[0] == pytest.approx(y2)
    assert np.all(np.diff(path) <= 1e-12)  # never increases
    assert path[0] - path[-1] == pytest.approx(res.error_reduction.sum(), rel=1e-9)
    resid = y - res.predict(P)
    assert path[-1] == pytest.approx(np.mean(resid**2), rel=1e-9)  # implicit = explicit


def test_pure_noise_selects_nothing_beyond_the_forced_constant():
    rng = np.random.default_rng(SEED)
    n = 3000
    P = np.column_stack([np.ones(n), rng.normal(size=(n, 8))])
    y = 0.3 + rng.normal(size=n)
    res = fos(P, y, ["1"] + [f"d{i}" for i in range(8)], force=["1"])
    print("noise:", res.terms, res.stop_reason)
    assert res.terms == ["1"]


def test_linearly_dependent_candidate_is_never_selected_twice():
    P, y, names = _system(SEED)
    P2 = np.column_stack([P, 3.0 * P[:, 3]])
    res = fos(
        P2,
        y,
        names + ["3*p3"],
        holdout=None,
        max_terms=P2.shape[1],
        min_reduction=0.0,
        noise_threshold=False,
    )
    assert not {"p3", "3*p3"} <= set(res.terms)
    assert "linearly dependent" in res.stop_reason


def test_block_holdout_is_deterministic_blocks():
    m = block_holdout(1000, fraction=0.25, block_len=50)
    assert m.sum() == 250 and np.array_equal(m, block_holdout(1000, fraction=0.25, block_len=50))
    assert m[150:200].all() and not m[:150].any()
    assert not block_holdout(100, fraction=0.25, block_len=50).any()  # too short: no hold-out


@pytest.mark.parametrize("bad", ["nan", "shape", "force", "names"])
def test_bad_arguments_raise_value_error(bad):
    P, y, names = _system(SEED, n=200)
    kwargs = {}
    if bad == "nan":
        y = y.copy()
        y[5] = np.nan
    elif bad == "shape":
        y = y[:-1]
    elif bad == "force":
        kwargs["force"] = ["nope"]
    elif bad == "names":
        names = names[:-1]
    with pytest.raises(ValueError):
        fos(P, y, names, **kwargs)
