"""Benchmark: per-step time of the state estimator against a naive EKF, in the same run.

One seeded 60 s drive of the hybrid plant (``live_sensors.random_drive``) is measured once by
the simulated sensors (CAN 83 Hz, IMU 100 Hz, GNSS); the messages that arrive in each control
period are then fed to each filter followed by ``predict`` for the period, and the wall time
of that whole step (all updates + predict) is recorded. Set-ups: GNSS at 20 Hz with 50 ms
latency (the default) and at 10 Hz with 100 ms latency (the robustness case), with a
20 ms period, and the latter with the closed loop's 100 ms control period.

The baseline is the textbook way to write the same filter (in this file, same state, same
measurement equations, same plant functions, same rewind-and-replay latency compensation):
fresh arrays each step (``np.eye``, ``np.diag``, ``np.linalg.inv`` for every update, a Python
list of copied states and covariances for the history). Both filters' position errors are
printed to show they compute the same thing.

    .venv/bin/python -m hmpc.tools.bench_estimator [--seed N] [--duration S] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np


def _stats(a_s) -> dict:
    a = np.asarray(a_s) * 1e3
    return {
        "p50_ms": float(np.percentile(a, 50)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
        "n": int(len(a)),
    }


class NaiveEkf:
    """The same 7-state EKF written plainly: allocates every step, history as a list."""

    def __init__(self, params, cfg):
        from hmpc.models.plant import HybridPlant

        self.plant = HybridPlant(params)
        self.cfg = cfg
        self.b = params.vehicle.wheelbase_m
        self.off, self.scale = params.steering.offset_rad, params.steering.scale
        self.x = None
        self.P = None
        self.t = -math.inf
        self.u = np.zeros(3)
        self.sw, self.t_sw, self.a, self.t_a = 0.0, -math.inf, 0.0, -math.inf
        self.zone = None
        self.hist: list = []  # (t, kind, payload, x, P, held)
        from scipy.stats import chi2

        self.gate = {m: chi2.ppf(cfg.gate_probability, m) for m in range(1, 5)}

    def _held(self):
        return (self.t, self.u.copy(), self.sw, self.t_sw, self.a, self.t_a, self.zone)

    def _set_held(self, h):
        self.t, u, self.sw, self.t_sw, self.a, self.t_a, self.zone = h
        self.u = u.copy()

    def _prop(self, t):
        c = self.cfg
        while self.t < t - 1e-12:
            dt = min(c.max_step_s, t - self.t)
            steer = self.sw if self.t - self.t_sw <= c.steer_input_max_age_s else self.u[0]
            u = np.array([steer + self.x[4] / self.scale, self.u[1], self.u[2]])
            imu = c.use_imu_accel and self.t - self.t_a <= c.imu_accel_max_age_s
            z = self.plant.select_zone(float(self.x[3]), self.zone)
            extra = self.a - self.plant.accel(z, u[1], u[2]) if imu else 0.0
            A, B = self.plant.jacobians(self.x[:4], u, z)
            r = self.plant.step(self.x[:4], u, dt, z, extra)
            self.x = np.concatenate([r.state, self.x[4:]])
            self.zone = r.zone
            F = np.eye(7)
            F[:4, :4] += A * dt
            F[:4, 4] = B[:, 0] * dt / self.scale
            if imu:
                F[3, 4] = 0.0
            q = (
                np.array(
                    [
                        c.position_walk_m_rts,
                        c.position_walk_m_rts,
                        c.heading_walk_rad_rts,
                        c.speed_walk_imu_mps_rts if imu else c.speed_walk_mps_rts,
                        c.delta_offset_walk_rad_rts,
                        c.gyro_bias_walk_radps_rts,
                        c.wheel_scale_walk_rts,
                    ]
                )
                ** 2
            )
            self.P = F @ self.P @ F.T + np.diag(q * dt)
            self.t += dt

    def _upd(self, H, y, R):
        S = H @ self.P @ H.T + R
        Si = np.linalg.inv(S)
        if float(y @ Si @ y) > self.gate[len(y)]:
            return False
        K = self.P @ H.T @ Si
        self.x = self.x + K @ y
        I_KH = np.eye(7) - K @ H
        self.P = I_KH @ self.P
        self.P = 0.5 * (self.P + self.P.T)
        return True

    def _apply(self, kind, t, p):
        self._prop(t)
        c, x = self.cfg, self.x
        if kind == "tick":
            self.u = np.array(p[:3])
            return
        if kind == "can":
            ws, swm = p
            if swm is not None:
                self.sw, self.t_sw = swm, t
            if ws is not None:
                d = self.off + self.scale * self.sw + x[4]
                cc = 0.5 * (1 + math.cos(d))
                H = np.zeros((1, 7))
                H[0, 3], H[0, 6], H[0, 4] = x[6] * cc, x[3] * cc, -0.5 * x[6] * x[3] * math.sin(d)
                self._upd(
                    H,
                    np.array([float(np.mean(ws)) - x[6] * x[3] * cc]),
                    np.array([[c.can_speed_mps**2]]),
                )
            return
        if kind == "imu":
            r, ax = p
            d = self.off + self.scale * self.sw + x[4]
            H = np.zeros((1, 7))
            H[0, 3], H[0, 4], H[0, 5] = math.sin(d) / self.b, x[3] * math.cos(d) / self.b, 1.0
            self._upd(
                H,
                np.array([r - x[3] * math.sin(d) / self.b - x[5]]),
                np.array([[c.imu_yaw_rate_radps**2]]),
            )
            if ax is not None:
                self.a, self.t_a = ax, t
            return
        gx, gy, gh, gv = p
        H = np.zeros((4, 7))
        H[0, 0] = H[1, 1] = H[2, 2] = H[3, 3] = 1.0
        y = np.array([gx - x[0], gy - x[1], math.remainder(gh - x[2], 2 * math.pi), gv - x[3]])
        R = np.diag(
            [c.gnss_position_m**2, c.gnss_position_m**2, c.gnss_heading_rad**2, c.gnss_speed_mps**2]
        )
        self._upd(H, y, R)

    def feed(self, kind, t, p):
        if self.x is None:
            if kind == "gnss":
                self.x = np.array([p[0], p[1], p[2], p[3], 0.0, 0.0, 1.0])
                c = self.cfg
                self.P = np.diag(
                    np.array(
                        [
                            c.init_position_m,
                            c.init_position_m,
                            c.init_heading_rad,
                            c.init_speed_mps,
                            c.init_delta_offset_rad,
                            c.init_gyro_bias_radps,
                            c.init_wheel_scale,
                        ]
                    )
                    ** 2
                )
                self.t = t
                self.hist.append(
                    (t, "tick", tuple(self.u), self.x.copy(), self.P.copy(), self._held())
                )
            elif kind == "tick":
                self.u = np.array(p[:3])
            return
        if t >= self.t:
            self._apply(kind, t, p)
            self.hist.append((t, kind, p, self.x.copy(), self.P.copy(), self._held()))
        else:  # rewind to the last event before t, insert, replay everything after
            i = max(k for k, h in enumerate(self.hist) if h[0] <= t)
            _, _, _, x, P, held = self.hist[i]
            self.x, self.P = x.copy(), P.copy()
            self._set_held(held)
            later = self.hist[i + 1 :]
            self.hist = self.hist[: i + 1]
            for tk, kk, pk in [(t, kind, p)] + [(h[0], h[1], h[2]) for h in later]:
                self._apply(kk, tk, pk)
                self.hist.append((tk, kk, pk, self.x.copy(), self.P.copy(), self._held()))
        while len(self.hist) > 1024:
            self.hist.pop(0)


def _events_per_tick(params, scfg, seed, duration_s, tick_s):
    from hmpc.models.sim.live_sensors import LiveSensors, random_drive

    tr = random_drive(params, duration_s, seed)
    sens = LiveSensors(params, scfg, seed)
    every = int(round(tick_s / (tr.t_s[1] - tr.t_s[0])))
    ticks, pending = [], []
    for i, t in enumerate(tr.t_s):
        pending += sens.observe(
            t, tr.states[i], tr.steering_wheel_angle_rad[i], tr.accel_mps2[i], tr.delta_rad[i]
        )
        if i % every == 0:
            ticks.append((t, pending, tuple(tr.u[i]), tr.states[i]))
            pending = []
    return ticks


def run(seed: int, duration_s: float) -> dict:
    from hmpc.controller.estimator import Estimator, EstimatorConfig
    from hmpc.models.params import load_params
    from hmpc.models.sim.live_sensors import SensorConfig
    from hmpc.tools.datafiles import PARAMS_DIR

    params = load_params(PARAMS_DIR / "report_2008.yaml", require_model=True)
    out = {"seed": seed, "duration_s": duration_s, "setups": {}}
    slow = SensorConfig(gnss_rate_hz=10.0, gnss_latency_s=0.1)
    for name, scfg, period in (
        ("gnss_20hz_50ms", SensorConfig(), 0.02),
        ("gnss_10hz_100ms", slow, 0.02),
        ("gnss_10hz_100ms_10hz", slow, 0.1),
    ):
        ecfg = EstimatorConfig.matching(scfg)
        ticks = _events_per_tick(params, scfg, seed, duration_s, period)
        hm, nv = Estimator(params, ecfg), NaiveEkf(params, ecfg)
        t_hm, t_nv, e_hm, e_nv = [], [], [], []
        for t, msgs, u, truth in ticks:
            c0 = time.perf_counter()
            for m in msgs:
                hm.feed(m, t)
            hm.predict(t, u)
            c1 = time.perf_counter()
            for m in msgs:
                v = m.values
                if m.kind == "can":
                    nv.feed(
                        "can",
                        max(m.t_meas_s, nv.t),
                        (v["wheel_speeds_mps"], v["steering_wheel_angle_rad"]),
                    )
                elif m.kind == "imu":
                    nv.feed("imu", max(m.t_meas_s, nv.t), (v["yaw_rate_radps"], v["accel_x_mps2"]))
                else:
                    nv.feed(
                        "gnss", m.t_meas_s, (v["x_m"], v["y_m"], v["heading_rad"], v["speed_mps"])
                    )
            nv.feed("tick", max(t, nv.t), u)
            c2 = time.perf_counter()
            if hm.initialized and nv.x is not None and t > 5.0:
                t_hm.append(c1 - c0)
                t_nv.append(c2 - c1)
                e_hm.append(math.hypot(*(hm.state()[:2] - truth[:2])))
                e_nv.append(math.hypot(*(nv.x[:2] - truth[:2])))
        s_hm, s_nv = _stats(t_hm), _stats(t_nv)
        out["setups"][name] = {
            "control_period_s": period,
            "hmpc": s_hm,
            "naive": s_nv,
            "ratio_p50": s_nv["p50_ms"] / s_hm["p50_ms"],
            "ratio_p99": s_nv["p99_ms"] / s_hm["p99_ms"],
            "position_rms_m": {
                "hmpc": float(np.sqrt(np.mean(np.square(e_hm)))),
                "naive": float(np.sqrt(np.mean(np.square(e_nv)))),
            },
            "gnss_replays": hm.stats["gnss"]["replays"],
        }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=60.0, metavar="S")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args(argv)
    res = run(args.seed, args.duration)
    print(
        f"estimator step (all messages of a control period + predict), seed {args.seed}, "
        f"{args.duration:.0f} s drive"
    )
    print(
        f"{'setup':21s} {'period':>6s} {'filter':7s} {'p50 ms':>8s} {'p99 ms':>8s} "
        f"{'max ms':>8s}  pos RMS m"
    )
    for name, r in res["setups"].items():
        per = f"{1e3 * r['control_period_s']:.0f} ms"
        for who in ("hmpc", "naive"):
            s = r[who]
            print(
                f"{name:21s} {per:>6s} {who:7s} {s['p50_ms']:8.3f} {s['p99_ms']:8.3f} "
                f"{s['max_ms']:8.3f}  {r['position_rms_m'][who]:.4f}"
            )
        print(
            f"{name:21s} {per:>6s} ratio naive/hmpc: p50 {r['ratio_p50']:.2f}x, "
            f"p99 {r['ratio_p99']:.2f}x ({r['gnss_replays']} rewinds)"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
