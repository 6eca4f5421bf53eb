"""Offline closed-loop replay of a recorded drive (``hmpc replay``): what hmpc would have done.

Two modes:

- **reference replay** (:func:`reference_replay`): the recording's path (x, y, heading) and
  speed become a :class:`Reference`; the controller drives the identified plant over the same
  course through ``controller.closed_loop.run_closed_loop`` (simulated sensors, the EKF), and
  the run is compared with what the car and its driver did: speed and steering differences,
  the distance from the driven path, pedal switches and zone transitions (car against
  controller) and the time windows where the two differ most;
- **log replay** (:func:`log_replay`), as openpilot's process replay does: the recorded feedback
  frames go through the drive loop (``controller/actuation/drive.py``: the same decoder,
  estimator, controller, limits and encoders as on a car) with no plant, on a simulated clock
  (``controller/actuation/replay_bus.py``), and the command frames hmpc would have sent are
  compared per signal with those on the log (e.g. openpilot's ``STEERING_LKA`` and
  ``ACC_CONTROL``). The run is deterministic: a sha256 over the sent frames names its output.

The log replay's reference is the drive dead-reckoned from the log's own CAN feedback (front
wheel speeds and steering-wheel angle through eq. 1 and eq. 7), the same integration the drive
loop's estimator runs: no GNSS reaches the bus, so a GNSS path would show up as estimator drift
that the controller "corrects" and that the car never saw.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from collections.abc import Callable

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.logs.frames import FrameTable
from hmpc.models.logs.recording import Recording
from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant
from hmpc.models.reference import Reference, front_speed, recording_reference

from hmpc.controller.closed_loop import run_closed_loop
from hmpc.controller.metrics import pedal_switches


@dataclass(frozen=True)
class ReplayConfig:
    """Comparison settings (each number with its reason)."""

    # Width of the windows where car and controller differ most [s]: a few seconds is one
    # manoeuvre (a lane change, a speed change) at highway speed.
    window_s: float = 5.0
    # How many such windows are reported (non-overlapping, largest first).
    n_windows: int = 3
    # Sent-frame timestamps are rounded to this many decimals [s] in the output hash: 0.1 ms,
    # far below the 10 ms tick, so the hash names the tick of every frame.
    hash_decimals: int = 4
    # Pedal positions above this count as pressed when counting switches [0..1] (the
    # limits' deadband).
    pedal_deadband: float = 1e-3


# ------------------------------------------------------------------ comparisons
def difference_figures(a: np.ndarray, b: np.ndarray) -> dict:
    """a - b over the samples where both are finite: RMS, max |.|, mean, the correlation of a
    and b (None when either is constant), and the sample count."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b)
    if not ok.any():
        return {
            "samples": 0,
            "rms_difference": None,
            "max_abs_difference": None,
            "mean_difference": None,
            "correlation": None,
        }
    d = a[ok] - b[ok]
    corr = None
    if ok.sum() > 2 and np.std(a[ok]) > 0 and np.std(b[ok]) > 0:
        corr = float(np.corrcoef(a[ok], b[ok])[0, 1])
    return {
        "samples": int(ok.sum()),
        "rms_difference": float(np.sqrt(np.mean(d**2))),
        "max_abs_difference": float(np.max(np.abs(d))),
        "mean_difference": float(np.mean(d)),
        "correlation": corr,
    }


def worst_windows(t_s: np.ndarray, diff: np.ndarray, width_s: float, n: int) -> list[dict]:
    """The ``n`` non-overlapping windows of ``width_s`` [s] with the largest RMS of ``diff``
    (NaN samples ignored), largest first: [{t0_s, t1_s, rms, max_abs}] on ``t_s``'s clock."""
    t, d = np.asarray(t_s, float), np.asarray(diff, float)
    ok = np.isfinite(d)
    t, d = t[ok], d[ok]
    if len(t) < 2:
        return []
    c2 = np.concatenate([[0.0], np.cumsum(d**2)])
    j = np.searchsorted(t, t + width_s, side="right")
    cnt = j - np.arange(len(t))
    rms = np.sqrt((c2[j] - c2[np.arange(len(t))]) / np.maximum(cnt, 1))
    full = t + width_s <= t[-1] + 1e-9
    if full.any():
        rms = np.where(full, rms, -1.0)
    out: list[dict] = []
    for i in np.argsort(-rms, kind="stable"):
        if rms[i] < 0 or len(out) >= n:
            break
        t0 = float(t[i])
        if any(t0 < w["t1_s"] and t0 + width_s > w["t0_s"] for w in out):
            continue
        seg = d[i : j[i]]
        out.append(
            {
                "t0_s": t0,
                "t1_s": t0 + width_s,
                "rms": float(rms[i]),
                "max_abs": float(np.max(np.abs(seg))),
            }
        )
    return out


# ------------------------------------------------------------------ reference replay
@dataclass
class ReferenceReplay:
    """A reference replay: the JSON figures and the arrays for the plots.

    Attributes:
        summary: KPIs, car-against-controller figures, windows (stable keys, SI units).
        run: the closed-loop result (``controller.closed_loop.ClosedLoopResult``).
        reference: the recorded drive as a reference.
        car: the car's channels on the run's time grid (speed_mps, steering_wheel_angle_rad,
            accel_pedal, brake_pedal, zone).
    """

    summary: dict
    run: object
    reference: Reference
    car: dict = field(default_factory=dict)


def _car_on_grid(rec: Recording, t_run: np.ndarray, plant: HybridPlant) -> dict:
    """The car's channels interpolated on the run's time [s from the recording's start]."""
    ch = rec.channels
    t = np.asarray(ch["time"], float) - float(ch["time"][0])

    def on(name, fill=np.nan):
        if name not in ch or not np.isfinite(ch[name]).any():
            return np.full(len(t_run), fill)
        y = np.asarray(ch[name], float)
        ok = np.isfinite(y)
        return np.interp(t_run, t[ok], y[ok])

    v = np.interp(t_run, t, np.nan_to_num(front_speed(rec)))
    return {
        "speed_mps": v,
        "steering_wheel_angle_rad": on("steering_wheel_angle"),
        "accel_pedal": on("accel_pedal", 0.0),
        "brake_pedal": on("brake_pedal", 0.0),
        "zone": plant.zone_schedule(v, None),
    }


def reference_replay(
    rec: Recording,
    params: Params,
    controller,
    *,
    plant_params: Params | None = None,
    control_period_s: float = 0.1,
    seed: int = 0,
    reference_source: str = "auto",
    config: ReplayConfig = ReplayConfig(),
    progress: Callable[[float, float], None] | None = None,
    adapter=None,
) -> ReferenceReplay:
    """The controller drives the identified plant along the recorded drive; compared with the car.

    Args:
        rec: the canonical recording of the drive.
        params: the controller's model (and the plant's unless ``plant_params``).
        controller: a ``controller.base.Controller``.
        plant_params: a different plant than the controller's model (model mismatch).
        control_period_s: controller period [s].
        seed: the simulated sensors' seed.
        reference_source: ``auto``, ``nav`` or ``can`` (see :func:`recording_reference`).
        config: the replay's settings (:class:`ReplayConfig`).
        progress: ``progress(fraction, t_s)`` (``run_closed_loop``'s).
        adapter: an online model estimator (``controller.adapt.ModelAdapter``) for the run;
            its ``adaptation`` goes into the summary.
    """
    name = str(rec.meta.get("path", "recording"))
    ref = recording_reference(rec, params, source=reference_source, name=name)
    res = run_closed_loop(
        controller,
        ref,
        params,
        plant_params=plant_params,
        control_period_s=control_period_s,
        seed=seed,
        progress=progress,
        adapter=adapter,
    )
    ch = res.recording.channels
    t = ch["time"]
    plant = HybridPlant(plant_params or params)
    car = _car_on_grid(rec, t, plant)
    minutes = max((t[-1] - t[0]) / 60.0, 1e-9)
    m = res.metrics
    ctl_kpi = {
        k: m[k]
        for k in (
            "speed_error_rms_mps",
            "lateral_error_rms_m",
            "pedal_switches_per_min",
            "zone_transitions_per_min",
            "solve_time_ms",
            "steps",
            "failures",
            "internal_errors",
            "speed_error_max_mps",
            "lateral_error_max_m",
        )
    }
    car_kpi = {
        "pedal_switches_per_min": pedal_switches(
            car["accel_pedal"], car["brake_pedal"], config.pedal_deadband
        )
        / minutes,
        "zone_transitions_per_min": int(np.count_nonzero(np.diff(car["zone"]))) / minutes,
    }
    diffs = {
        "speed_mps": difference_figures(ch["speed"], car["speed_mps"]),
        "steering_wheel_angle_rad": difference_figures(
            ch["steering_wheel_angle"], car["steering_wheel_angle_rad"]
        ),
        "lateral_m": difference_figures(res.lateral_error_m, np.zeros(len(t))),
        "zone": {
            "agreement_fraction": float(np.mean(res.zone == car["zone"])),
            "samples": int(len(t)),
        },
    }
    win = {
        "speed_mps": worst_windows(
            t, ch["speed"] - car["speed_mps"], config.window_s, config.n_windows
        ),
        "lateral_m": worst_windows(t, res.lateral_error_m, config.window_s, config.n_windows),
        "steering_wheel_angle_rad": worst_windows(
            t,
            ch["steering_wheel_angle"] - car["steering_wheel_angle_rad"],
            config.window_s,
            config.n_windows,
        ),
    }
    summary = {
        "mode": "reference",
        "reference": {
            "name": name,
            "source": reference_source,
            "duration_s": ref.duration_s,
            "length_m": ref.length_m,
        },
        "kpis": {"controller": ctl_kpi, "car": car_kpi},
        "differences": diffs,
        "windows": win,
        "seed": seed,
        "control_period_s": control_period_s,
        "compared": "the controller on the identified plant (simulated sensors + EKF) "
        "against the recorded car along the recorded path and speed: speed "
        "and steering-wheel angle (controller minus car), distance from the "
        "driven path, pedal switches and zone transitions per minute",
    }
    if adapter is not None:
        summary["adaptation"] = m["adaptation"]
        summary["adaptation_details"] = m["adaptation_details"]
    return ReferenceReplay(summary, res, ref, car)


# ------------------------------------------------------------------ log replay
@dataclass
class LogReplay:
    """A log replay: the JSON figures, the aligned command signals and the loop's own result.

    Attributes:
        summary: see :func:`log_replay`.
        signals: per compared signal: t_s (from the log's start), hmpc, log, engaged (bool).
        drive: the drive loop's ``DriveResult``.
        sent: the frames hmpc sent (``can.Message``, simulated timestamps).
    """

    summary: dict
    signals: dict
    drive: object
    sent: list


def _decode_commands(times, ids, datas, spec) -> dict:
    """Raw-scaled values of a command message's value and enable signals: name -> array."""
    m = spec.message
    names = list(spec.values.values()) + list(spec.enable)
    out: dict[str, list[float]] = {n: [] for n in names}
    tt = []
    for t, fid, data in zip(times, ids, datas):
        if fid != m.frame_id:
            continue
        d = m.decode(bytes(data), decode_choices=False)
        tt.append(t)
        for n in names:
            out[n].append(float(d[n]))
    return {"t_s": np.asarray(tt, float), **{k: np.asarray(v, float) for k, v in out.items()}}


def _held(t_src: np.ndarray, y: np.ndarray, t: np.ndarray, max_age_s: float) -> np.ndarray:
    """``y`` sampled at ``t`` by zero-order hold (NaN before the first sample or when the last
    one is older than ``max_age_s``)."""
    if len(t_src) == 0:
        return np.full(len(t), np.nan)
    i = np.searchsorted(t_src, t, side="right") - 1
    ok = (i >= 0) & (t - t_src[np.maximum(i, 0)] <= max_age_s)
    return np.where(ok, y[np.maximum(i, 0)], np.nan)


def _log_flag(frames: FrameTable, profile, item: str, bus: int):
    """(t_s, flag 0/1) of a profile feedback item decoded from the log, or None."""
    it = profile.feedback.get(item)
    if it is None:
        return None
    msg = profile.db.get_message_by_name(it.message)
    sel = np.flatnonzero((frames.arb_id == msg.frame_id) & (frames.bus == bus))
    vals = [
        float(
            it.flag(
                float(
                    msg.decode(bytes(frames.data[i, : frames.dlc[i]]), decode_choices=False)[
                        it.signal
                    ]
                )
            )
        )
        for i in sel
    ]
    return frames.t_s[sel].astype(float), np.asarray(vals, float)


def check_log(frames: FrameTable, profile):
    """The replay bus's frames of ``frames`` for ``profile`` and the log time [s] at which the
    car first accepts commands. InputError (one line naming the log and the message) when the
    profile's bus holds no frames, lacks a feedback message the loop needs, or the car never
    accepts commands in the log."""
    from hmpc.controller.actuation.replay_bus import ReplaySource

    path = str(frames.path)
    cmd_ids = {spec.message.frame_id for spec in profile.commands.values()}
    source = ReplaySource(frames, profile.bus, exclude_ids=cmd_ids)
    if len(source) == 0:
        raise InputError(f"no frames on bus {profile.bus} (the profile's bus)", path)
    _check_feedback(source, profile, path)
    return source, _first_accepting(frames, profile)


def _check_feedback(source, profile, path: str) -> None:
    """InputError naming the log and the message when the served bus lacks the feedback the
    loop needs (wheel speeds and steering angle of the signal map, the status of the profile)."""
    present = set(np.unique(source.arb_id).tolist())
    need = []
    for ch in ("speed", "steering_wheel_angle"):
        spec = profile.signal_map.channels.get(ch)
        if spec is not None:
            need.append(spec.message)
    need += [it.message for k, it in profile.feedback.items() if k.startswith("accepts_")]
    for name in dict.fromkeys(need):
        fid = profile.db.get_message_by_name(name).frame_id
        if fid not in present:
            raise InputError(
                f"no {name} (0x{fid:X}) frames on bus {profile.bus}: the drive loop "
                f"needs them as feedback",
                path,
            )


def log_replay(
    frames: FrameTable,
    profile,
    params: Params,
    controller,
    reference: Reference,
    *,
    candump: str | Path | None = None,
    config: ReplayConfig = ReplayConfig(),
    progress: Callable[[float, float], None] | None = None,
    adapter=None,
) -> LogReplay:
    """The log's feedback frames through the drive loop with no plant, on a simulated clock.

    Args:
        frames: the log (``models.logs.canlog.read_log``).
        profile: the actuation profile (its bus is served; its command ids are not: hmpc sends
            them now, and the log's own are the comparison).
        params: the controller's model.
        controller: the controller the loop runs.
        reference: the drive as a reference, on the log's clock (0 = the log's first frame).
        candump: where the loop writes its candump (default: a temporary file).
        config: the replay's settings (:class:`ReplayConfig`).
        progress: ``progress(fraction, t_s)`` as the simulated clock advances.
        adapter: an online model estimator for the drive loop (its ``adaptation`` in the
            summary): what the logged car's feedback teaches the model.

    Returns:
        :class:`LogReplay`; ``summary`` holds ``hash`` (sha256 of the sent frames),
        ``differences`` and ``windows`` per signal, ``engaged_s`` and the loop's figures.
    """
    from hmpc.controller.actuation.candump import audit_candump
    from hmpc.controller.actuation.drive import DriveConfig, DriveLoop

    path = str(frames.path)
    source, t_accept = check_log(frames, profile)
    t0, span = float(source.t_s[0]), float(source.t_s[-1] - source.t_s[0])
    t_accept -= t0
    # the replay's operator engages when the logged car first accepts commands (as openpilot
    # was engaged on the log), not at the loop's default 0.3 s after start
    # Dead reckoning from the logged feedback, not the EKF: the EKF predicts with the loop's
    # own commands, which the logged car never executed (openpilot drove it); with them the
    # comma minute's ACCEL_CMD difference grew from 0.33 to 1.16 m/s^2 RMS
    dcfg = replace(
        DriveConfig(),
        engage_at_s=max(DriveConfig().engage_at_s, t_accept),
        estimator="dead_reckoning",
    )
    clock = _ProgressClock(t0, span, progress)
    with tempfile.TemporaryDirectory() as tmp:
        dump = Path(candump) if candump is not None else Path(tmp) / "replay.log"
        loop = DriveLoop(
            profile,
            params,
            controller,
            reference,
            {"interface": "hmpc_replay", "channel": "replay", "source": source, "clock": clock},
            dump,
            duration_s=span,
            config=dcfg,
            clock=clock,
            adapter=adapter,
        )
        drive = loop.run()
        audit = audit_candump(profile, params, dump)
    sent = source.sent
    signals = _compare_signals(frames, profile, sent, drive, t0)
    summary = {
        "mode": "log",
        "log": path,
        "profile": profile.name,
        "hash": {
            "sha256": source.sent_sha256(config.hash_decimals),
            "frames": len(sent),
            "timestamp_decimals": config.hash_decimals,
            "over": "arbitration id, data bytes and the simulated send time of "
            "every frame hmpc sent",
        },
        "log_span_s": span,
        "frames_served": int(source.pos),
        "differences": {},
        "windows": {},
        "engaged_s": {},
        "kpis": {
            **{
                k: drive.summary[k]
                for k in (
                    "steps",
                    "ticks",
                    "frames_sent",
                    "limit_clips",
                    "blocked_at_encoder",
                    "engaged_s",
                    "stop",
                    "failures",
                    "solve_time_ms",
                )
            },
            "limit_violations": audit["limit_violations"],
        },
        "limit_violations": audit["limit_violations"],
        "limit_audit": audit,
    }
    if adapter is not None:
        summary["adaptation"] = drive.summary["adaptation"]
        summary["adaptation_details"] = drive.summary["adaptation_details"]
    for name, s in signals.items():
        both = s["engaged_log"] & s["engaged_hmpc"]
        dt = float(np.median(np.diff(s["t_s"]))) if len(s["t_s"]) > 1 else 0.0
        summary["engaged_s"][name] = {
            "log": float(s["engaged_log"].sum() * dt),
            "hmpc": float(s["engaged_hmpc"].sum() * dt),
            "both": float(both.sum() * dt),
        }
        d = difference_figures(np.where(both, s["hmpc"], np.nan), np.where(both, s["log"], np.nan))
        d["unit"] = s["unit"]
        d["all_samples"] = difference_figures(s["hmpc"], s["log"])
        d["hmpc_abs_max"] = float(np.nanmax(np.abs(s["hmpc"]))) if len(s["hmpc"]) else None
        d["log_abs_max"] = (
            float(np.nanmax(np.abs(s["log"]))) if np.isfinite(s["log"]).any() else None
        )
        summary["differences"][name] = d
        summary["windows"][name] = worst_windows(
            s["t_s"],
            np.where(both, s["hmpc"] - s["log"], np.nan),
            config.window_s,
            config.n_windows,
        )
    tr = drive.trace
    eng = np.asarray(tr.get("engaged", []), float) > 0.5
    if eng.any():
        d = difference_figures(np.asarray(tr["sw_cmd"])[eng], np.asarray(tr["sw"])[eng])
        d["unit"] = "rad"
        d["note"] = (
            "hmpc's steering-wheel angle command (the MPC's, before the inner angle "
            "loop) against the measured angle, which the log's controller produced"
        )
        summary["differences"]["steering_wheel_angle_cmd_rad"] = d
        summary["windows"]["steering_wheel_angle_cmd_rad"] = worst_windows(
            np.asarray(tr["t_s"])[eng],
            (np.asarray(tr["sw_cmd"]) - np.asarray(tr["sw"]))[eng],
            config.window_s,
            config.n_windows,
        )
    summary["compared"] = (
        "per command signal, hmpc's frame (what the drive loop sent) minus the "
        "log's latest frame of the same message, over the samples where both "
        "were engaged (the log: the message's enable bit, else the car's "
        "cruise state; hmpc: the loop engaged); times from the log's first "
        "frame [s]"
    )
    return LogReplay(summary, signals, drive, sent)


def _first_accepting(frames: FrameTable, profile) -> float:
    """Log time [s] at which every ``accepts_*`` status of the profile first holds; InputError
    naming the log and the statuses when the car never accepts commands in it."""
    flags = [
        (k, _log_flag(frames, profile, k, profile.bus))
        for k in profile.feedback
        if k.startswith("accepts_")
    ]
    if not flags:
        return float(frames.t_s[0])
    grid = np.unique(np.concatenate([f[0] for _, f in flags]))
    ok = np.ones(len(grid), bool)
    for _, (t, v) in flags:
        ok &= _held(t, v, grid, np.inf) > 0.5
    if not ok.any():
        names = ", ".join(
            f"{profile.feedback[k].message}.{profile.feedback[k].signal}" for k, _ in flags
        )
        raise InputError(
            f"the car never accepts commands in this log ({names} never all "
            f"active): there is nothing to replay through the drive loop",
            str(frames.path),
        )
    return float(grid[np.argmax(ok)])


class _ProgressClock:
    """The replay's simulated clock (``controller.simclock.SimClock``) reporting progress
    every tenth."""

    def __init__(self, t0_s: float, span_s: float, progress):
        from hmpc.controller.simclock import SimClock

        self._c = SimClock(t0_s)
        self._t0, self._span, self._progress, self._last = t0_s, max(span_s, 1e-9), progress, -1

    def monotonic(self) -> float:
        return self._c.monotonic()

    def time(self) -> float:
        return self._c.time()

    def sleep(self, seconds: float) -> None:
        self._c.sleep(seconds)
        if self._progress is not None:
            frac = min((self._c.t_s - self._t0) / self._span, 1.0)
            tenth = int(frac * 10)
            if tenth != self._last:
                self._last = tenth
                self._progress(tenth / 10, self._c.t_s - self._t0)


def _compare_signals(frames: FrameTable, profile, sent: list, drive, t0: float) -> dict:
    """hmpc's and the log's command signals on hmpc's frame times (from the log's start [s])."""
    bus = profile.bus
    on_bus = frames.bus == bus
    lt, lid = frames.t_s[on_bus].astype(float), frames.arb_id[on_bus]
    ldata = [bytes(frames.data[i, : frames.dlc[i]]) for i in np.flatnonzero(on_bus)]
    st = np.array([m.timestamp for m in sent], float)
    sid = np.array([m.arbitration_id for m in sent], np.int64)
    sdata = [bytes(m.data) for m in sent]
    tr = drive.trace
    eng = np.asarray(tr.get("engaged", []), float) > 0.5
    t_eng = np.asarray(tr.get("t_s", []), float)[eng]
    cruise = _log_flag(frames, profile, "accepts_long", bus)
    out = {}
    for spec in profile.commands.values():
        log_c = _decode_commands(lt, lid, ldata, spec)
        if len(log_c["t_s"]) == 0:
            continue  # the log holds none of this message: nothing to compare
        ours = _decode_commands(st, sid, sdata, spec)
        t = ours["t_s"]
        age = 2.5 * spec.period_s
        if spec.enable:
            en_log = _held(log_c["t_s"], log_c[spec.enable[0]], t, age) > 0.5
        elif cruise is not None:
            en_log = _held(cruise[0], cruise[1], t, 1.0) > 0.5
        else:
            en_log = np.ones(len(t), bool)
        en_h = (
            (t - t0 >= t_eng[0] - 1e-9) & (t - t0 <= t_eng[-1] + 1e-9)
            if len(t_eng)
            else np.zeros(len(t), bool)
        )
        if spec.enable:
            en_h &= ours[spec.enable[0]] > 0.5
        for q, sig in spec.values.items():
            s = spec.message.get_signal_by_name(sig)
            out[f"{spec.message.name}.{sig}"] = {
                "t_s": t - t0,
                "hmpc": ours[sig],
                "log": _held(log_c["t_s"], log_c[sig], t, age),
                "engaged_log": en_log,
                "engaged_hmpc": en_h,
                "unit": s.unit or "raw",
                "quantity": q,
            }
    return out
