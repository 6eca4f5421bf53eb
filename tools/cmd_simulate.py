"""``hmpc simulate``: the report's experiments on the ground-truth simulator, or the closed loop.

Two uses:

- ``hmpc simulate --experiment NAME --params P.yaml --out rec.csv [--seed N] [--json F]``:
  a canonical recording of one of the report's experiments (section III) on a plant with
  known parameters (``models.sim``), for ``hmpc identify``.
- ``hmpc simulate --params P.yaml (--scenario NAME | --reference REF.csv)
  [--controller mpc|nmpc|pid] [--plant-params OTHER.yaml] [--out RUN.csv] [--plots DIR]
  [--json FILE] [--seed N]``: a controller drives the hybrid plant along a reference. The
  JSON holds ``speed_error_rms_mps``, ``lateral_error_rms_m``, ``pedal_switches_per_min``,
  ``zone_transitions_per_min``, ``solve_time_ms`` {p50, p99, max}, ``steps``, ``failures``,
  ``internal_errors`` (controller bugs; the first traceback goes to stderr), the smoothness
  figures (``steering_reversals_per_min`` {1deg, 5deg}, ``steering_rate_rms_radps``,
  ``accel_pedal_rate_rms_ps``, ``brake_pedal_rate_rms_ps``), the ``sensors`` used and, under
  ``details``, more (``details.estimator``: the estimate's error against the truth).

  The controller sees the plant only through simulated car sensors and the EKF
  (``controller.estimator``): ``--speed-noise``, ``--position-noise``,
  ``--sensor-noise-scale``, ``--gnss-rate``, ``--gnss-latency``, ``--gnss-outage T0:T1``,
  ``--sensor-fault KIND@T0:T1[:VALUE]``.

  ``--adapt`` learns the model on line (``controller.adapt``) and controls with it while it
  is valid; the JSON's ``adaptation`` holds {KEY: {initial, final, ci95, converged_t_s,
  valid, used, ...}} per learned value (KEY the fleet contract's dotted parameter key) and
  ``details.adaptation`` its cost per control step and counts. ``--learned FILE`` restores
  and saves the learned state.

  Whether the car did what was asked: ``limits`` (time at each actuator limit) and
  ``stalls`` (the reference moves, the car does not); a run that could not follow its
  reference (``followed: false``, its ``not_followed`` reasons) says so and exits 1.
"""

from __future__ import annotations

import math
import sys

from hmpc.models.errors import InputError
from hmpc.models.reference import load_reference

from hmpc.controller.build import make_controller
from hmpc.tools.common import (
    CONTROLLERS,
    add_accept_unidentifiable,
    add_adapt_arguments,
    adapter_from_args,
    finish_adapter,
    load_model_params,
    write_json,
)

#: what ``--out`` holds, for the CLI's check of output paths (tools/cli.py)
OUTPUTS = {"out": "the recording"}


def add_arguments(p) -> None:
    p.add_argument(
        "--params",
        required=True,
        metavar="P.yaml",
        help="parameter file: the controller's model (and the plant's)",
    )
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--scenario",
        metavar="NAME",
        help="closed loop on a named scenario: arcs, circles, figure8, ramps, "
        "ramp_sequence, idle_hold",
    )
    what.add_argument(
        "--reference",
        metavar="REF.csv",
        help="closed loop on a reference CSV (time, x, y, speed[, heading]) or along "
        "a canonical recording's driven path and speed",
    )
    what.add_argument(
        "--experiment",
        metavar="NAME",
        help="simulate one of the report's experiments (open loop driver) into a "
        "canonical recording: arcs, circles, figure8, ramps, ramp_sequence, "
        "open_loop",
    )
    p.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default="mpc",
        help="closed-loop controller (default mpc)",
    )
    add_accept_unidentifiable(p)
    p.add_argument(
        "--plant-params",
        metavar="OTHER.yaml",
        help="run the controller against a plant built from these parameters (model mismatch)",
    )
    p.add_argument("--out", metavar="RUN.csv", help="write the canonical recording here")
    p.add_argument("--plots", metavar="DIR", help="write labelled PNG plots into DIR")
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise (default 0)")
    p.add_argument(
        "--dt",
        type=float,
        default=0.2,
        choices=(0.1, 0.2),
        help="MPC stage length [s] (default 0.2)",
    )
    p.add_argument(
        "--horizon", type=float, default=10.0, metavar="S", help="MPC horizon [s] (default 10)"
    )
    p.add_argument(
        "--control-period",
        type=float,
        default=0.1,
        metavar="S",
        help="controller period [s]; the plant runs at 50 Hz (default 0.1)",
    )
    p.add_argument(
        "--speed-noise",
        type=float,
        default=0.05,
        metavar="MPS",
        help="std of the speed noise of the wheel speeds and the GNSS speed [m/s] "
        "(default 0.05, wheel-speed noise of a real car)",
    )
    p.add_argument(
        "--position-noise",
        type=float,
        default=None,
        metavar="M",
        help="std of the GNSS position noise [m] (default 0.4 x --speed-noise: 0.02, an RTK fix)",
    )
    p.add_argument(
        "--sensor-noise-scale",
        type=float,
        default=1.0,
        metavar="K",
        help="multiply every random sensor error by K (default 1; 3 for the robustness runs)",
    )
    p.add_argument(
        "--gnss-rate",
        type=float,
        default=20.0,
        metavar="HZ",
        help="GNSS/INS fix rate [Hz] (default 20)",
    )
    p.add_argument(
        "--gnss-latency",
        type=float,
        default=0.05,
        metavar="S",
        help="GNSS/INS fix latency [s] (default 0.05)",
    )
    p.add_argument(
        "--gnss-outage",
        action="append",
        default=[],
        metavar="T0:T1",
        help="no GNSS fix from T0 to T1 [s on the reference's clock] (repeatable)",
    )
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME:KEY=VALUE,...",
        help="concealed physics in the simulated car that the controller's model "
        "lacks, e.g. road_grade:grade_rad=0.03, steering_lag:tau_s=0.15, "
        "idle_creep:accel_mps2=0.5,creep_speed_mps=2 (repeatable)",
    )
    p.add_argument(
        "--sensor-fault",
        action="append",
        default=[],
        metavar="KIND@T0:T1[:VALUE]",
        help="a sensor fault on the simulated messages: frozen_wheel_speed (one wheel "
        "speed keeps its value), frozen_yaw_rate, yaw_rate_spike (VALUE rad/s "
        "added) from T0 to T1 [s] (repeatable)",
    )
    add_adapt_arguments(p)
    p.add_argument(
        "--no-transition-penalty",
        action="store_true",
        help="MPC without the zone-transition penalty (for comparison)",
    )
    p.add_argument(
        "--noise",
        choices=("typical", "quantised", "none"),
        default="typical",
        help="--experiment: sensor noise level (default typical)",
    )
    p.add_argument(
        "--rate",
        type=float,
        default=50.0,
        metavar="HZ",
        help="--experiment: recording rate [Hz] (default 50)",
    )


def _check_positive(option: str, value: float) -> None:
    """InputError naming ``option`` unless ``value`` is a finite number > 0."""
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"{option} must be a finite number > 0, got {value:g}")


def _save(rec, path: str) -> None:
    """Write ``rec`` to ``--out`` (InputError naming the file when it cannot be written)."""
    try:
        rec.save(path)
    except OSError as exc:
        raise InputError(f"cannot write the recording ({exc.strerror or exc})", path) from None


def run(args) -> int:

    _check_positive("--rate", args.rate)
    _check_positive("--control-period", args.control_period)
    _check_positive("--horizon", args.horizon)
    params = load_model_params(args.params, args, "simulate")
    if args.experiment is not None:
        return _run_experiment(args, params, write_json)
    return _run_closed_loop(args, params, write_json)


def _run_experiment(args, params, write_json) -> int:
    from hmpc.models.sim import simulator as sim  # imported only when used
    from hmpc.models.sim.plans import EXPERIMENTS

    if args.experiment not in EXPERIMENTS:
        raise InputError(
            f"unknown experiment '{args.experiment}' (choose from {', '.join(EXPERIMENTS)})"
        )
    if not args.out:
        raise InputError("--experiment needs --out REC.csv")
    if args.plant_params or args.plots:
        raise InputError(
            "--plant-params and --plots belong to closed-loop runs (--scenario/--reference)"
        )
    rec = sim.simulate_experiment(
        args.experiment, params, seed=args.seed, rate_hz=args.rate, noise=args.noise
    )
    _save(rec, args.out)
    t = rec.channels["time"]
    summary = {
        "experiment": args.experiment,
        "seed": args.seed,
        "noise": args.noise,
        "rate_hz": args.rate,
        "rows": int(len(t)),
        "duration_s": float(t[-1] - t[0]) if len(t) else 0.0,
        "channels": [c for c in rec.channels if c != "time"],
        "out": str(args.out),
    }
    print(
        f"hmpc simulate: experiment {args.experiment}: {summary['rows']} rows, "
        f"{summary['duration_s']:.1f} s -> {args.out}"
    )
    write_json(args.json, summary)
    return 0


def _run_closed_loop(args, params, write_json) -> int:
    from hmpc.controller.closed_loop import control_updates, run_closed_loop
    from hmpc.models.report.closed_loop import plot_closed_loop
    from hmpc.models.sim.effects import parse_effect
    from hmpc.models.sim.scenarios import make_scenario

    if args.horizon <= 0 or abs(args.horizon / args.dt - round(args.horizon / args.dt)) > 1e-6:
        raise InputError(f"--horizon {args.horizon} must be a positive multiple of --dt {args.dt}")
    sensors = _sensor_config(args)
    effects = [parse_effect(e) for e in args.effect]
    plant_params = (
        load_model_params(args.plant_params, args, "simulate") if args.plant_params else None
    )
    ref = (
        make_scenario(args.scenario, params)
        if args.scenario is not None
        else load_reference(args.reference, params)
    )
    ctl = make_controller(
        args.controller,
        params,
        dt_s=args.dt,
        horizon_s=args.horizon,
        transition_penalty=not args.no_transition_penalty,
        accept_unidentifiable=args.accept_unidentifiable,
    )
    print(
        f"hmpc simulate: {args.controller} on {ref.name} ({ref.duration_s:.1f} s), "
        f"seed {args.seed}",
        file=sys.stderr,
    )

    def progress(fraction: float, t_s: float) -> None:
        print(
            f"  closed loop {ref.name}: {100 * fraction:3.0f}% (t = {t_s:.1f} s)",
            file=sys.stderr,
            flush=True,
        )

    k = sensors.noise_scale
    adapter = adapter_from_args(
        args,
        params,
        args.control_period,
        "simulate",
        yaw_rate_noise_radps=max(k * sensors.gyro_noise_radps, 1e-4),
        accel_noise_mps2=max(k * sensors.accel_noise_mps2, 1e-3),
    )
    res = run_closed_loop(
        ctl,
        ref,
        params,
        plant_params=plant_params,
        control_period_s=args.control_period,
        seed=args.seed,
        sensors=sensors,
        progress=progress,
        effects=effects or None,
        adapter=adapter,
        sensor_faults=_sensor_faults(args),
    )
    m = res.metrics
    if res.internal_errors:
        t_err, tb = res.internal_errors[0]
        print(
            f"hmpc simulate: {len(res.internal_errors)} internal controller error(s), the "
            f"first at t = {t_err:.2f} s (controlled stop each time):\n{tb}",
            file=sys.stderr,
        )
    if args.out:
        _save(res.recording, args.out)
    payload = {
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
            "steering_reversals_per_min",
            "steering_rate_rms_radps",
            "accel_pedal_rate_rms_ps",
            "brake_pedal_rate_rms_ps",
            "followed",
            "not_followed",
            "limits",
            "stalls",
        )
    }
    if adapter is not None:
        payload["adaptation"] = m["adaptation"]
    payload.update(
        {
            "controller": args.controller,
            "reference": ref.name,
            "plant_params": args.plant_params,
            "seed": args.seed,
            "sensors": _sensor_echo(sensors),
            "effects": [e.describe() for e in effects],
            "details": {k: v for k, v in m.items() if k not in payload},
        }
    )
    if args.plots:
        try:
            zp = plant_params or params
            payload["plots"] = plot_closed_loop(
                res,
                ref,
                args.plots,
                args.controller,
                [(z.name, z.v_min_mps, z.v_max_mps) for z in zp.zones],
                control_updates(res),
            )
            if adapter is not None:
                payload["plots"].append(_plot_adaptation(adapter, args, plant_params))
        except OSError as exc:
            raise InputError(
                f"cannot write the plots ({exc.strerror or exc})", args.plots
            ) from None
    _print_summary(payload)
    finish_adapter(args, adapter, "simulate", float(m["duration_s"]))
    write_json(args.json, payload)
    if not m["followed"]:
        print(
            f"hmpc simulate: the car did not follow its reference: {'; '.join(m['not_followed'])}",
            file=sys.stderr,
        )
        return 1
    return 0


def _plot_adaptation(adapter, args, plant_params) -> str:
    """The learned parameters against time (``--plots``); the plant's values as the truth
    when the plant is another file."""
    from pathlib import Path

    from hmpc.models.report.adaptation import plot_adaptation

    truth = None
    if plant_params is not None:
        from hmpc.controller.adapt.config import KEY_STEER_OFFSET, KEY_STEER_SCALE, zone_key

        truth = {
            KEY_STEER_OFFSET: plant_params.steering.offset_rad,
            KEY_STEER_SCALE: plant_params.steering.scale,
        }
        if adapter.inputs == "pedals":
            for z in plant_params.zones:
                truth.update(
                    {
                        zone_key(z.name, c): getattr(z, c)
                        for c in ("offset_mps2", "scale_mps2", "brake_scale_mps2")
                    }
                )
    t, v, sg = adapter.history.arrays()
    t0 = adapter.t0_s or 0.0
    return plot_adaptation(
        t - t0,
        adapter.keys,
        v,
        sg,
        Path(args.plots) / "adaptation.png",
        title="learned parameters (estimate, 95 % interval)",
        truth=truth,
    )


def _sensor_faults(args) -> list:
    """``--sensor-fault KIND@T0:T1[:VALUE]`` (InputError naming a bad one)."""
    from hmpc.controller.closed_loop import SENSOR_FAULTS, SensorFault

    out = []
    for text in args.sensor_fault:
        kind, _, span = text.partition("@")
        parts = span.split(":")
        try:
            if kind not in SENSOR_FAULTS or len(parts) not in (2, 3):
                raise ValueError
            out.append(
                SensorFault(
                    kind,
                    float(parts[0]),
                    float(parts[1]),
                    float(parts[2]) if len(parts) == 3 else 0.0,
                )
            )
        except ValueError:
            raise InputError(
                f"--sensor-fault {text!r}: expected KIND@T0:T1[:VALUE] with KIND "
                f"one of {', '.join(SENSOR_FAULTS)} and T0 < T1"
            ) from None
    return out


def _print_summary(p: dict) -> None:
    st = p["solve_time_ms"]
    print(
        f"controller {p['controller']} on {p['reference']}: "
        f"speed error RMS {p['speed_error_rms_mps']:.3f} m/s, "
        f"lateral error RMS {p['lateral_error_rms_m']:.3f} m, "
        f"pedal switches {p['pedal_switches_per_min']:.1f}/min, "
        f"zone transitions {p['zone_transitions_per_min']:.1f}/min, "
        f"solve time p50/p99/max {st['p50']:.2f}/{st['p99']:.2f}/{st['max']:.2f} ms, "
        f"{p['steps']} steps, {p['failures']} failures, "
        f"{p['internal_errors']} internal errors"
    )
    lim, stl = p["limits"], p["stalls"]
    at = [f"{k.replace('_s', '')} {v:.1f} s" for k, v in lim.items() if v > 0]
    print(
        f"  actuators at their limits: {', '.join(at) if at else 'none'}; stalled "
        f"{stl['total_s']:.1f} s (longest {stl['longest_s']:.1f} s)"
        + ("" if p["followed"] else f"; DID NOT FOLLOW: {'; '.join(p['not_followed'])}")
    )
    rv = p["steering_reversals_per_min"]
    print(
        f"  smoothness: steering reversals >= 1/5 deg {rv['1deg']:.1f}/{rv['5deg']:.1f} per "
        f"min, steering-wheel rate RMS {p['steering_rate_rms_radps']:.3f} rad/s, pedal rate "
        f"RMS accel {p['accel_pedal_rate_rms_ps']:.3f} brake "
        f"{p['brake_pedal_rate_rms_ps']:.3f} /s (rates: change per control update / period)"
    )


def _sensor_config(args):
    """The simulated sensors from the options (InputError naming the bad option)."""
    from hmpc.models.sim.live_sensors import SensorConfig

    if not args.speed_noise >= 0:
        raise InputError("--speed-noise must be >= 0")
    pos = round(0.4 * args.speed_noise, 9) if args.position_noise is None else args.position_noise
    if not pos >= 0:
        raise InputError("--position-noise must be >= 0")
    outages = []
    for w in args.gnss_outage:
        try:
            a, b = (float(q) for q in w.split(":"))
        except ValueError:
            raise InputError(f"--gnss-outage {w!r}: expected T0:T1 in seconds") from None
        if not a < b:
            raise InputError(f"--gnss-outage {w!r}: T0 must be before T1")
        outages.append((a, b))
    try:
        return SensorConfig(
            speed_noise_mps=args.speed_noise,
            gnss_speed_noise_mps=args.speed_noise,
            position_noise_m=pos,
            noise_scale=args.sensor_noise_scale,
            gnss_rate_hz=args.gnss_rate,
            gnss_latency_s=args.gnss_latency,
            gnss_outages=tuple(outages),
        )
    except ValueError as exc:  # e.g. a negative rate: name it as an option
        msg = (
            str(exc)
            .replace("noise_scale", "--sensor-noise-scale")
            .replace("gnss_rate_hz", "--gnss-rate")
            .replace("gnss_latency_s", "--gnss-latency")
        )
        raise InputError(msg) from None


def _sensor_echo(cfg) -> dict:
    """The sensor settings of a run, for its JSON."""
    return {
        "speed_noise_mps": cfg.speed_noise_mps,
        "position_noise_m": cfg.position_noise_m,
        "noise_scale": cfg.noise_scale,
        "gnss_rate_hz": cfg.gnss_rate_hz,
        "gnss_latency_s": cfg.gnss_latency_s,
        "gnss_outages_s": [list(w) for w in cfg.gnss_outages],
        "can_rate_hz": cfg.can_rate_hz,
        "imu_rate_hz": cfg.imu_rate_hz,
    }
