"""How the accepted candidates of one subsystem combine into findings: of two alternative
descriptions only the better stays (:func:`drop_alternatives`), static longitudinal terms are
refitted on top of an accepted delay or lag (:func:`stack_on_dynamics`) and a delay or lag on
top of the best static term (:func:`stack_dynamics_on_static`), and the actuator's response
as a dead time and a lag fitted together (:func:`actuator_response`) judges a dead time
against a lag when their replays are within the speed resolution.
"""

from __future__ import annotations

import numpy as np

from hmpc.models.catalogue import ALTERNATIVES
from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose.candidates import Resolution, accept, candidate, fos_selects
from hmpc.models.diagnose.common import DiagnoseConfig, corr_length
from hmpc.models.diagnose.lon_joint import joint_response

#: the actuator's dynamics among the longitudinal hypotheses (alternatives to each other)
DYNAMICS = ("actuator_delay", "actuator_lag")


def drop_alternatives(
    cands: list, res: Resolution = Resolution(), response: dict | None = None
) -> None:
    """Of two alternative descriptions of one subsystem only the better stays a finding.

    Better is the lower held-out free-run RMSE, unless the two differ by less than the
    channel's resolution: then the replay cannot tell them apart and the equation-error BIC
    over all samples (the same baseline below both, one extension parameter each) decides. A
    v and a v^2 resistance are such a pair: the zone offsets hold the constant part, so the
    two differ only in how the slope changes from zone to zone, which a 10-s free run hardly
    sees. Only for linear terms (one coefficient each, the same zone structure): a dead time
    and a lag are fitted against a smoothed derivative that itself looks like a lag, so their
    equation-error likelihoods are no fair judge between them.

    A dead time and a lag within the resolution are judged by their joint fit (``response``,
    :func:`actuator_response`): the one that alone fits as well as the joint fit, where the
    other does not. When either alone does (the recording fixes the total delay, not its
    split), the dead time is named: of two responses with the same effective delay it costs
    the more phase (omega d against atan(omega tau), unbounded against at most 90 deg), so a
    controller designed on it keeps its margin on the other; a lag would promise a margin
    the car may not have."""
    tol = {
        "speed": res.speed_mps,
        "heading": res.heading_rad,
        "speed_vs_gnss": res.speed_vs_gnss_mps,
    }
    for group in ALTERNATIVES:
        for sub in ("steering", "longitudinal"):
            g = [c for c in cands if c["effect"] in group and c["subsystem"] == sub and c["_ok"]]
            if len(g) > 1:
                g.sort(key=lambda c: c["heldout_rmse_after"])
                a, b = g[0], g[1]
                if (
                    a["effect"] in lon.LINEAR_EXT
                    and b["effect"] in lon.LINEAR_EXT
                    and a["channel"] == b["channel"]
                    and a["heldout_rmse_before"] == b["heldout_rmse_before"]
                    and b["heldout_rmse_after"] - a["heldout_rmse_after"]
                    < tol.get(a["channel"], 0.0)
                    and b["delta_bic"] < a["delta_bic"]
                ):
                    g[0], g[1] = b, a
                elif (
                    {a["effect"], b["effect"]} == set(DYNAMICS)
                    and response is not None
                    and a["heldout_rmse_before"] == b["heldout_rmse_before"]
                    and b["heldout_rmse_after"] - a["heldout_rmse_after"]
                    < tol.get(a["channel"], 0.0)
                ):
                    pick = _dynamics_by_joint_fit(response)
                    if pick is not None and pick != a["effect"]:
                        g[0], g[1] = b, a
                        b["chosen_because"] = (
                            f"{a['effect']} replays only "
                            f"{b['heldout_rmse_after'] - a['heldout_rmse_after']:.4f} m/s better "
                            f"(within the speed resolution); the joint dead-time + lag fit: "
                            f"{response['split']}"
                            + (
                                "; so the dead time is named: for the same delay it costs the "
                                "more phase"
                                if response["lr_lag_only"] <= 3.84
                                else ""
                            )
                        )
                for c in g[1:]:
                    c["_ok"] = False
                    c["why"] = f"alternative to {g[0]['effect']}, " + (
                        "which explains more"
                        if g[0]["heldout_rmse_after"] <= c["heldout_rmse_after"]
                        else "the better description within the channel's resolution"
                    )
                g[0]["alternatives"] = [
                    {
                        "effect": c["effect"],
                        "parameters": c["parameters"],
                        "heldout_rmse_after": c["heldout_rmse_after"],
                    }
                    for c in g[1:]
                ]


def stack_on_dynamics(ld, cands, lon_scores, cfg, cl, res) -> None:
    """Refit the static longitudinal extensions on top of an accepted delay or lag: a drag or
    grade that only looked useful because the actuator's dynamics were missing is dropped, one
    that helps on top of them is kept (scored against the model with the dynamics)."""
    dyn = [
        c
        for c in cands
        if c["subsystem"] == "longitudinal"
        and c["_ok"]
        and c["effect"] in ("actuator_delay", "actuator_lag")
    ]
    if not dyn:
        return
    top = min(dyn, key=lambda c: c["heldout_rmse_after"])
    key = lon.NONLINEAR[top["effect"]]
    base = {key: top["parameters"][key]}
    b = lon_scores[top["effect"]]
    for c in [
        c
        for c in cands
        if c["subsystem"] == "longitudinal"
        and c["channel"] == "speed"
        and c["effect"] in lon.LINEAR_EXT
    ]:
        h = c["effect"]
        s = lon.evaluate(ld, h, cfg, cl, base=base)
        ok, why = accept(b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic, res.speed_mps, cfg)
        if ok and not fos_selects(ld, h, spec=s.model.spec):
            ok, why = False, "FOS does not select the term on its hold-out"
        if ok:
            lon_scores[("on_top", h)] = s
            new = candidate(
                h,
                "longitudinal",
                "speed",
                b,
                s,
                b.heldout_rmse_mps,
                s.heldout_rmse_mps,
                True,
                f"accepted on top of {top['effect']}",
                cfg.window_lon_s,
            )
            new["on_top_of"] = {top["effect"]: base}
            if h == "road_grade":
                new["parameters"]["grade_source"] = ld.grade_source
            c.clear()
            c.update(new)
        elif c["_ok"]:
            c["_ok"] = False
            c["why"] = f"explained by {top['effect']}: on top of it {why}"


def stack_dynamics_on_static(ld, cands, lon_scores, cfg, cl, res) -> None:
    """An actuator's delay or lag can hide behind a larger static mismatch (a grade change an
    ACC compensates only over seconds dwarfs a response of a few tenths of a second). When no
    delay or lag is a finding on its own but a static term is, each is refitted on top of the
    best static term (its parameters searched again) and scored against that model."""
    lon_speed = [c for c in cands if c["subsystem"] == "longitudinal" and c["channel"] == "speed"]
    if any(c["_ok"] and c["effect"] in DYNAMICS for c in lon_speed):
        return
    static = [c for c in lon_speed if c["_ok"] and c["effect"] in lon.LINEAR_EXT]
    if not static:
        return
    top = min(static, key=lambda c: c["heldout_rmse_after"])
    b = lon_scores[top["effect"]]
    base = {
        "ext_name": top["effect"],
        "comp_rate_per_s": b.model.spec.comp_rate_per_s,
        "creep_speed_mps": b.model.spec.creep_speed_mps,
    }
    below = {k: v for k, v in top["parameters"].items() if isinstance(v, float)}
    for c in [c for c in lon_speed if c["effect"] in DYNAMICS]:
        h = c["effect"]
        s = lon.evaluate(ld, h, cfg, cl, base=base)
        ok, why = accept(b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic, res.speed_mps, cfg)
        new = candidate(
            h,
            "longitudinal",
            "speed",
            b,
            s,
            b.heldout_rmse_mps,
            s.heldout_rmse_mps,
            ok,
            f"accepted on top of {top['effect']}" if ok else f"on top of {top['effect']}: {why}",
            cfg.window_lon_s,
        )
        new["on_top_of"] = {top["effect"]: below}
        if not ok:  # the hypothesis alone stays on record; the stacked try goes beside it
            c["why"] = f"{c['why']}; {new['why']}"
            c["stacked"] = {
                k: new[k]
                for k in (
                    "parameters",
                    "intervals",
                    "heldout_rmse_before",
                    "heldout_rmse_after",
                    "gain",
                    "on_top_of",
                )
            }
            continue
        lon_scores[("on_top", h)] = s
        c.clear()
        c.update(new)


def _dynamics_by_joint_fit(response: dict) -> str | None:
    """The dead time or the lag as the joint fit judges them (:func:`drop_alternatives`):
    the one that alone fits within likelihood ratio 3.84 of the joint fit where the other does
    not; the dead time when both do; None when neither does (the joint fit needs both)."""
    lr_d, lr_l = response.get("lr_dead_time_only"), response.get("lr_lag_only")
    if lr_d is None or lr_l is None:
        return None
    if lr_d <= 3.84:
        return "actuator_delay"
    return "actuator_lag" if lr_l <= 3.84 else None


def _split_verdict(lr_dead: float, lr_lag: float) -> str:
    """What the likelihood ratios of the dead time alone and the lag alone against their joint
    fit say when the joint fit does not need both (3.84: chi-square, 1 dof, 95 %)."""
    if lr_dead <= 3.84 and lr_lag <= 3.84:
        return (
            f"it cannot tell a dead time from a lag (either alone fits within likelihood "
            f"ratio 3.84 of the joint fit: dead time {lr_dead:.1f}, lag {lr_lag:.1f}): it "
            "fixes the total delay, not its split"
        )
    one, other, lr_one, lr_other = (
        ("a lag", "a dead time", lr_lag, lr_dead)
        if lr_lag <= 3.84
        else ("a dead time", "a lag", lr_dead, lr_lag)
    )
    return (
        f"{one} alone fits as well as the joint fit (likelihood ratio {lr_one:.1f}), "
        f"{other} alone does not ({lr_other:.1f} > 3.84): the response is {one}"
    )


def actuator_response(
    cands: list, ch: dict, ld: lon.LonData, lon_scores: dict, cfg: DiagnoseConfig, cl: float
) -> dict | None:
    """The actuator's response as a dead time and a lag fitted together
    (:func:`lon_joint.joint_response`), on top of the model the single delay and lag were
    scored against: its total effective delay d + tau with intervals, its held-out speed
    RMSE, and whether the recording can tell a dead time from a lag (``ch``: the channels,
    for the cross-check on the GNSS speed). None when no delay or lag was found or hinted at.
    ``hmpc diagnose`` records it in ``channels["speed"]["response"]`` and as a note. It names
    no finding of its own (the catalogue's delay and lag are the descriptions that are
    ranked); it decides between the two when their replays are within the speed resolution
    (:func:`drop_alternatives`)."""
    lon_speed = [c for c in cands if c["subsystem"] == "longitudinal" and c["channel"] == "speed"]
    dyn = [
        c
        for c in lon_speed
        if c["effect"] in DYNAMICS
        and (c["_ok"] or max(c["gain"], c.get("stacked", {}).get("gain", 0.0)) >= cfg.min_gain / 2)
    ]
    if not dyn:  # no delay or lag found or hinted at (half a finding's gain, alone or on
        return None  # top of a static term): nothing to qualify, and the map costs seconds
    # the static term of the final model: the one a delay or lag was fitted on top of, or one
    # accepted on top of the delay or lag
    below = next(
        (
            next(iter(c.get("on_top_of") or c.get("stacked", {}).get("on_top_of") or {}))
            for c in dyn
            if c.get("on_top_of") or "stacked" in c
        ),
        None,
    )
    below = below or next(
        (
            c["effect"]
            for c in lon_speed
            if c["_ok"]
            and c["effect"] in lon.LINEAR_EXT
            and set(c.get("on_top_of") or ()) & set(DYNAMICS)
        ),
        None,
    )
    base, before = {}, lon_scores[None].heldout_rmse_mps
    if below is not None and below in lon_scores:
        sp = lon_scores[below].model.spec
        base = {
            "ext_name": sp.term,
            "comp_rate_per_s": sp.comp_rate_per_s,
            "creep_speed_mps": sp.creep_speed_mps,
        }
        before = lon_scores[below].heldout_rmse_mps
    r = joint_response(ld, base, cfg, cl)
    after = r["heldout_rmse_mps"]
    r.update(
        on_top_of=below,
        heldout_rmse_before=before,
        gain=(before - after) / before if before > 0 and np.isfinite(after) else 0.0,
    )
    iv = r["intervals"]
    split = (
        "no delay or lag beyond the model's"
        if iv["effective_delay_s"][0] == 0.0 and r["gain"] < cfg.min_gain
        else "it separates a dead time from a lag"
        if r["separable"]
        else _split_verdict(r["lr_dead_time_only"], r["lr_lag_only"])
    )
    r["split"] = split
    r["verdict"] = (
        f"response of the acceleration to {r['input']}"
        + (f" on top of {below}" if below else "")
        + f": dead time {r['dead_time_s']:.2f} s [{iv['dead_time_s'][0]:.2f}, "
        f"{iv['dead_time_s'][1]:.2f}] and lag {r['tau_s']:.2f} s [{iv['tau_s'][0]:.2f}, "
        f"{iv['tau_s'][1]:.2f}] fitted together, effective delay d + tau "
        f"{r['effective_delay_s']:.2f} s [{iv['effective_delay_s'][0]:.2f}, "
        f"{iv['effective_delay_s'][1]:.2f}] (63 % of a step), held-out speed RMSE "
        f"{before:.3f} -> {after:.3f} m/s ({100 * r['gain']:.0f} %); {split}"
    )
    other = _response_on_gnss_speed(ch, ld, base, cfg)
    if other is not None:
        r["gnss_speed"] = other
        oi = other["intervals"]["effective_delay_s"]
        r["verdict"] += (
            f"; measured on the GNSS speed instead (an independent sensor): d + tau "
            f"{other['effective_delay_s']:.2f} s [{oi[0]:.2f}, {oi[1]:.2f}]"
        )
    return r


def _response_on_gnss_speed(
    ch: dict, ld: lon.LonData, base: dict, cfg: DiagnoseConfig
) -> dict | None:
    """The joint dead time + lag of the same inputs with the GNSS ground speed as the speed: a
    cross-check of the response on a sensor independent of the wheel speeds (their own
    filtering or timing would show as a different delay). None without a usable GNSS speed."""
    g = ch.get("gps_speed")
    if g is None or np.isfinite(np.asarray(g, float)).mean() < 0.8:
        return None
    lg = lon.prepare({**ch, "speed": np.asarray(g, float)}, ld.zones, cfg)
    if (lg.ok & (lg.vs > cfg.v_stop_mps)).sum() < int(20.0 / lg.dt):
        return None
    cl = corr_length(lon.residual(lg, lon.fit(lg, lon.LonSpec(), lg.ok)))
    r = joint_response(lg, base, cfg, cl)
    return {
        k: r[k]
        for k in ("dead_time_s", "tau_s", "effective_delay_s", "intervals", "heldout_rmse_mps")
    }
