"""The estimator's filter core: an extended Kalman filter over the plant, at its current time.

State (7, controller/estimator/config.py): the plant's ``[x_m, y_m, psi_rad, v_mps]``
(``models.plant``: local ENU, the front-wheel point of eq. 1) augmented with three slowly
varying sensor/model errors that the car's own data make observable and that otherwise bias
the plant state:

- ``delta_offset_rad``: a correction to eq. 7's road-wheel angle (``delta = offset + scale *
  sw + delta_offset``). It absorbs a steering map known only to +-13 % (the comma minute) and
  understeer at speed; the gyro observes it through the yaw rate ``v sin(delta) / b``.
- ``gyro_bias_radps``: the yaw-rate sensor's bias (the simulator draws up to +-0.002 rad/s).
  Separable from ``delta_offset`` because it does not scale with speed and GNSS heading sees
  the integral of the true yaw rate.
- ``wheel_speed_scale``: tyre rolling radius error (wheel speeds read ``scale * v``; the comma
  minute's wheel mean reads 0.8 % below GNSS). GNSS speed and position observe it; it keeps
  speed honest through a GNSS outage.

Process model: the report's eq. 1 + eq. 7 + eq. 8 of ``models.plant``, the one place they
are written: ``HybridPlant.step`` for the mean (zone hysteresis, exact in speed, standstill
clamp) and ``bicycle_jacobian`` for the covariance. The prediction runs a few hundred times a
second, so both are written out in :meth:`Ekf._propagate` on Python floats, operation
for operation, with the plant's zone lists and eq. 8 coefficients
(``tests/estimator/test_estimator_speed.py`` holds them to the plant: the mean to the bit, ``F`` to
``HybridPlant.jacobians``); a plant with opt-in extensions is stepped by ``HybridPlant.step``
itself. The ``delta_offset`` state enters by folding it into the steering input, ``sw +
delta_offset / scale``; eq. 1's derivative with respect to the road-wheel angle is its
column of ``F``.
When the IMU supplies a longitudinal acceleration it replaces eq. 8 in the speed propagation
(``use_imu_accel``). Propagation sub-steps are at most ``max_step_s``; the three extra states
are random walks. The covariance is propagated with ``F = I + A dt`` and a diagonal process
noise (random-walk densities in :class:`EstimatorConfig`).

Events (:meth:`Ekf._apply`): a predict tick (new held inputs), a CAN message, an IMU sample, a
GNSS fix, each applied at a time no earlier than the filter's (the message API and the
out-of-sequence replay are controller/estimator/estimator.py's).

Outliers: every update is gated on its normalised innovation squared ``y' S^-1 y`` against the
chi-square quantile with the update's degrees of freedom at ``gate_probability`` (0.999: a
consistent filter rejects 1 in 1000 good measurements; a 10 m jump on 2 cm GNSS scores about
10^5 against a threshold of 18.5 for a four-value fix). Rejections are counted per sensor in
``stats``. After ``gnss_reinit_after`` consecutive rejected fixes the filter
trusts GNSS again (the fix, not the filter, was right: e.g. after a long outage the
dead-reckoned state drifted): position and heading are reset to the fix with the initial
uncertainty, counted as ``reinit``.

Allocation and cost: the filter, Jacobian and measurement buffers are allocated once in
``__init__``; a step writes into them (flat ``memoryview`` s give their elements as Python
floats). Per event: ``P = F P F'`` is two 7x7 products and the process noise one BLAS
``daxpy`` on P's diagonal; a one-value update (CAN speed, yaw rate) is ``P h``, one ``ddot``,
``daxpy`` for the state and ``dger`` for ``P -= PH' HP / s``, all in place (P symmetric to a
few ulps; each GNSS update symmetrises it exactly); a GNSS update solves ``S^-1 [H P | y]``
by Cholesky (LAPACK ``dposv``); what it still allocates is its few small products.
``tools/bench_mpc.py`` prints the estimator's time per control period.
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
from scipy.linalg.blas import daxpy, ddot, dger
from scipy.linalg.lapack import dposv
from scipy.stats import chi2

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant
from hmpc.models.zones import zone_with_hysteresis

from hmpc.controller.estimator.config import (
    IBR,
    IDOFF,
    IKWS,
    IPSI,
    IV,
    IX,
    IY,
    NXE,
    SENSORS,
    EstimatorConfig,
)


def float_view(a: np.ndarray) -> memoryview[float]:
    """A flat memoryview of a float64 array, whose items are Python floats: element access
    without numpy scalars. The casts say what the type stubs cannot (numpy declares the buffer
    protocol for Python >= 3.12 only; a memoryview's items are int unless its format is a
    float one)."""
    return cast("memoryview[float]", memoryview(cast(Any, a)))


#: event kinds (:meth:`Ekf._apply`; the event log's first field)
EVENT_TICK, EVENT_CAN, EVENT_IMU, EVENT_GNSS = 0, 1, 2, 3


def _zone_bands(v_min_mps, v_max_mps, hysteresis_mps: float) -> list[tuple[float, float]]:
    """Per zone, the speeds [m/s] for which ``models.zones.zone_with_hysteresis(v, zone, ...,
    clamp=True)`` keeps ``zone`` (its band widened by the hysteresis; the first zone has no
    lower edge, the last none above). A cache of that rule's first test: outside the band the
    estimator calls the rule itself (``tests/estimator/test_estimator_speed.py`` checks they
    agree)."""
    n = len(v_max_mps)
    return [
        (
            -math.inf if z == 0 else v_min_mps[z] - hysteresis_mps,
            v_max_mps[z] + hysteresis_mps if z < n - 1 else math.inf,
        )
        for z in range(n)
    ]


class Ekf:
    """Extended Kalman filter over the plant state at its current time; see the module
    docstring. :class:`~hmpc.controller.estimator.estimator.Estimator` adds the message API
    and the event log.

    Args:
        params: the controller's model (geometry, steering map, zones).
        config: noise and settings.
    """

    def __init__(self, params: Params, config: EstimatorConfig | None = None):
        if not params.is_model:
            raise ValueError("the estimator needs a parameter file with steering and zones")
        self.params = params
        self.cfg = cfg = config or EstimatorConfig()
        self.plant = plant = HybridPlant(params)
        veh = params.vehicle
        self._b = float(veh.wheelbase_m)
        self._track_r = float(
            veh.track_rear_m if veh.track_rear_m is not None else veh.track_front_m
        )
        assert params.steering is not None  # is_model
        self._off = float(params.steering.offset_rad)
        self._scale = float(params.steering.scale)
        self._lever = (float(cfg.gnss_offset_m[0]), float(cfg.gnss_offset_m[1]))
        self._gate = {m: float(chi2.ppf(cfg.gate_probability, m)) for m in range(1, 5)}
        self._gate1 = self._gate[1]
        # the plant's zones and eq. 8 as Python floats for the scalar prediction (plant.py's
        # own lists); a plant with opt-in extensions is stepped by HybridPlant.step itself
        self._zone_args = (plant._v_min_list, plant._v_max_list, plant.hysteresis_mps)
        self._zone_keep = _zone_bands(*self._zone_args)
        self._eq8 = plant._eq8
        self._plant_step = getattr(plant, "ext", None) is not None
        self._max_step = float(cfg.max_step_s)
        self._sw_age = float(cfg.steer_input_max_age_s)
        self._imu_age = float(cfg.imu_accel_max_age_s) if cfg.use_imu_accel else -math.inf
        # filter buffers
        self._x = np.zeros(NXE)
        self._P = np.zeros((NXE, NXE))
        self._F = np.eye(NXE)
        self._FT = self._F.T  # a view: F' for P = F P F'
        self._PT = self._P.T  # a view: P in Fortran order, for BLAS's in-place rank-one update
        self._Pflat = self._P.reshape(-1)  # a view: its diagonal is every NXE + 1-th element
        # flat float views of x, P, F: element access on Python floats, without numpy scalars
        self._xm = float_view(self._x)
        self._Pm = float_view(self._Pflat)
        self._Fm = float_view(self._F.reshape(-1))
        self._geometry = (self._off, self._scale, self._b)  # eq. 7 offset, scale; wheelbase
        self._tmp = np.zeros((NXE, NXE))
        self._u4 = np.zeros(3)
        self._prediction_buffers = (self._F, self._FT, self._Fm, self._P, self._tmp, self._Pflat)
        self._q = (
            np.array(
                [
                    cfg.position_walk_m_rts,
                    cfg.position_walk_m_rts,
                    cfg.heading_walk_rad_rts,
                    cfg.speed_walk_mps_rts,
                    cfg.delta_offset_walk_rad_rts,
                    cfg.gyro_bias_walk_radps_rts,
                    cfg.wheel_scale_walk_rts,
                ]
            )
            ** 2
        )
        self._q_imu_v = cfg.speed_walk_imu_mps_rts**2
        self._q_imu = self._q.copy()  # the same with the IMU driving the speed
        self._q_imu[IV] = self._q_imu_v
        self._diag = self._P.reshape(-1)[:: NXE + 1]  # a view on P's diagonal
        self._init_var = (
            np.array(
                [
                    cfg.init_position_m,
                    cfg.init_position_m,
                    cfg.init_heading_rad,
                    cfg.init_speed_mps,
                    cfg.init_delta_offset_rad,
                    cfg.init_gyro_bias_radps,
                    cfg.init_wheel_scale,
                ]
            )
            ** 2
        )
        # update buffers per dimension m = 1..4 (GNSS)
        self._H = {m: np.zeros((m, NXE)) for m in range(1, 5)}
        self._PHt = {m: np.zeros((NXE, m)) for m in range(1, 5)}
        self._S = {m: np.zeros((m, m)) for m in range(1, 5)}
        self._S_diag = {m: self._S[m].reshape(-1)[:: m + 1] for m in range(1, 5)}  # views
        self._B = {m: np.zeros((m, NXE + 1)) for m in range(1, 5)}  # [H P | y]
        self._half = np.full((), 0.5)  # a 0-d array: a Python float in a ufunc costs more
        self._y = {m: np.zeros(m) for m in range(1, 5)}
        self._R = {m: np.zeros(m) for m in range(1, 5)}
        self._Hm = {m: float_view(self._H[m].reshape(-1)) for m in range(1, 5)}
        self._ym = {m: float_view(self._y[m]) for m in range(1, 5)}
        self._Rm = {m: float_view(self._R[m]) for m in range(1, 5)}
        # one-value updates: a row H per measurement (its zeros never change; its other
        # elements written through a memoryview) and P H'
        self._h_speed = np.zeros(NXE)  # IV, IKWS, IDOFF
        self._h_yaw = np.zeros(NXE)  # IV, IDOFF; IBR = 1
        self._h_yaw[IBR] = 1.0
        self._h_wyaw = np.zeros(NXE)  # IV, IDOFF, IKWS
        self._hm_speed, self._hm_yaw, self._hm_wyaw = (
            float_view(h) for h in (self._h_speed, self._h_yaw, self._h_wyaw)
        )
        self._ph1 = np.zeros(NXE)
        self._r_speed = cfg.can_speed_mps**2
        self.stats: dict[str, dict[str, float]] = {
            s: {"accepted": 0, "rejected": 0} for s in SENSORS
        }
        self.stats["gnss"].update(too_old=0, replays=0, reinit=0, latency_max_s=0.0)
        self._counting = True
        self._clear_held()

    def _clear_held(self) -> None:
        self._t = -math.inf
        self._u = [0.0, 0.0, 0.0]
        self._sw_meas, self._t_sw = 0.0, -math.inf
        self._a_imu, self._t_aimu = 0.0, -math.inf
        self._zone: int | None = None
        self._gnss_rejects = 0

    def _count(self, sensor: str, ok: bool) -> None:
        if self._counting:
            self.stats[sensor]["accepted" if ok else "rejected"] += 1

    def _steer(self, t: float) -> float:
        """Steering-wheel angle the wheels follow at ``t`` [rad]: the CAN angle while fresh."""
        if t - self._t_sw <= self._sw_age:
            return self._sw_meas
        return self._u[0]

    def _propagate_to(self, t: float) -> None:
        """Predict from the filter's time to ``t`` [s] in equal sub-steps of at most
        ``max_step_s``. The held inputs and their freshness (CAN steering angle, IMU
        acceleration) are those at the start, for every sub-step."""
        t0 = self._t
        dt_total = t - t0
        if dt_total <= 0.0:
            return
        n = max(int(math.ceil(dt_total / self._max_step - 1e-9)), 1)
        dt = dt_total / n
        sw = self._sw_meas if t0 - self._t_sw <= self._sw_age else self._u[0]
        imu = t0 - self._t_aimu <= self._imu_age
        for _ in range(n):
            self._propagate(dt, sw, imu)
        self._t = t

    def _propagate(self, dt: float, sw: float, imu: bool) -> None:
        """One prediction sub-step of ``dt`` [s] with the steering-wheel angle ``sw`` [rad]
        held; ``imu``: the IMU's acceleration replaces eq. 8's.

        The mean is ``HybridPlant.step`` (eq. 1, 7, 8; exact in speed, midpoint in heading and
        position, standstill clamp) written out here on Python floats, operation for
        operation (``tests/estimator/test_estimator_speed.py`` checks they agree to the bit); the
        covariance is ``F P F' + Q dt`` with eq. 1's Jacobian at the start of the step written
        into ``F`` (``bicycle_jacobian`` with respect to the road-wheel angle, which is also
        the derivative with respect to ``delta_offset``)."""
        xm = self._xm
        px, py, psi, v, doff = xm[IX], xm[IY], xm[IPSI], xm[IV], xm[IDOFF]
        ap, bp = self._u[1], self._u[2]
        zone = self._zone
        if zone is not None:
            lo, hi = self._zone_keep[zone]
            if not lo <= v <= hi:
                zone = zone_with_hysteresis(v, zone, *self._zone_args, clamp=True)
        else:
            zone = zone_with_hysteresis(v, zone, *self._zone_args, clamp=True)
        off_z, sc_z, br_z = self._eq8[zone]
        acc = off_z + sc_z * ap - br_z * bp  # eq. 8 (models.plant.zone_accel)
        extra = self._a_imu - acc if imu else 0.0
        off, scale, b = self._geometry
        u0 = sw + doff / scale
        delta = off + scale * u0  # eq. 7
        sd, cd = math.sin(delta), math.cos(delta)
        if self._plant_step:  # a plant with extensions: its own step
            u = self._u4
            u[0], u[1], u[2] = u0, ap, bp
            res = self.plant.step(self._x[:4], u, dt, zone, extra)
            self._x[:4] = res.state
            zone = res.zone
        else:
            a = acc + extra
            v0 = max(v, 0.0)
            v1 = v0 + a * dt
            if v1 < 0.0:  # stops within the step and stays stopped
                t_move = v0 / -a if a < 0 else 0.0
                v1 = 0.0
                dist = 0.5 * v0 * t_move
            else:
                dist = 0.5 * (v0 + v1) * dt
            dpsi = dist * sd / b
            ang = psi + 0.5 * dpsi + delta
            xm[IX] = px + dist * math.cos(ang)
            xm[IY] = py + dist * math.sin(ang)
            xm[IPSI] = psi + dpsi
            xm[IV] = v1
        self._zone = zone
        # F = I + A dt at the start of the step (flat index NXE * row + column); eq. 8's
        # speed row has no state in it
        c, s = math.cos(psi + delta), math.sin(psi + delta)
        F, FT, Fm, P, tmp, Pflat = self._prediction_buffers
        Fm[2] = Fm[4] = -v * s * dt  # x row: d/dpsi, d/ddelta_offset
        Fm[3] = c * dt  # x row: d/dv
        Fm[9] = Fm[11] = v * c * dt  # y row: d/dpsi, d/ddelta_offset
        Fm[10] = s * dt  # y row: d/dv
        Fm[17] = sd / b * dt  # psi row: d/dv
        Fm[18] = v * cd / b * dt  # psi row: d/ddelta_offset
        F.dot(P, out=tmp)
        tmp.dot(FT, out=P)
        # P's diagonal += q dt, in place (every NXE + 1-th element of the flat P)
        daxpy(self._q_imu if imu else self._q, Pflat, NXE, dt, 0, 1, 0, NXE + 1)

    def _update(self, m: int, sensor: str, angle_row: int = -1) -> bool:
        """Gated update with ``self._H[m]``, ``self._y[m]`` (z - h), ``self._R[m]`` (variances).

        ``S = H P H' + R`` is factorised once (Cholesky, LAPACK ``dposv``) and solved for
        ``S^-1 [H P | y]``: the gain's transpose and ``S^-1 y`` without an inverse. A
        non-positive-definite ``S`` (a broken covariance) is a rejected measurement."""
        H, y, S, PHt, B, P = self._H[m], self._y[m], self._S[m], self._PHt[m], self._B[m], self._P
        if angle_row >= 0:
            y[angle_row] = math.remainder(y[angle_row], 2.0 * math.pi)
        P.dot(H.T, out=PHt)
        H.dot(PHt, out=S)
        np.add(self._S_diag[m], self._R[m], out=self._S_diag[m])
        B[:, :NXE] = PHt.T  # H P (P is symmetric)
        B[:, NXE] = y
        _, X, info = dposv(S, B)
        if info != 0:
            self._count(sensor, False)
            return False
        Si_y = X[:, NXE]
        if float(y.dot(Si_y)) > self._gate[m]:
            self._count(sensor, False)
            return False
        self._x += PHt.dot(Si_y)  # K y
        P -= PHt.dot(X[:, :NXE])  # K H P
        np.add(P, P.T, out=self._tmp)
        np.multiply(self._tmp, self._half, out=P)  # exactly symmetric again
        self._count(sensor, True)
        return True

    def _update1(self, h: np.ndarray, y: float, r: float, sensor: str) -> bool:
        """Gated one-value update: measurement row ``h``, innovation ``y`` (z - h(x)), noise
        variance ``r``. No inverse; the state and the rank-one covariance update ``P -= PH' HP
        / s`` in place by BLAS (positional arguments: f2py parses keywords slowly)."""
        ph = self._ph1
        self._P.dot(h, out=ph)
        s = ddot(h, ph) + r
        ok = y * y / s <= self._gate1
        if ok:
            daxpy(ph, self._x, NXE, y / s)  # x += K y
            dger(-1.0 / s, ph, ph, 1, 1, self._PT, 1, 1, 1)  # P -= PH' HP / s
        if self._counting:
            self.stats[sensor]["accepted" if ok else "rejected"] += 1
        return ok

    def _yaw_update(self, z: float, sigma: float, sensor: str, biased: bool) -> None:
        """A yaw-rate measurement ``z`` [rad/s] (1-sigma ``sigma``): eq. 1's ``v sin(delta)/b``,
        plus the gyro bias (``biased``) or times the wheel-speed scale (the wheels' yaw rate)."""
        xm = self._xm
        v, doff = xm[IV], xm[IDOFF]
        sw = self._sw_meas if self._t - self._t_sw <= self._sw_age else self._u[0]
        d = self._off + self._scale * sw + doff
        sd, cd = math.sin(d), math.cos(d)
        b = self._b
        if biased:
            h, hm = self._h_yaw, self._hm_yaw
            hm[IV] = sd / b
            hm[IDOFF] = v * cd / b
            y = z - (v * sd / b + xm[IBR])
        else:
            kws = xm[IKWS]
            h, hm = self._h_wyaw, self._hm_wyaw
            hm[IV] = kws * sd / b
            hm[IDOFF] = kws * v * cd / b
            hm[IKWS] = v * sd / b
            y = z - kws * v * sd / b
        self._update1(h, y, sigma * sigma, sensor)

    def _speed_update(self, t: float, z: float) -> None:
        """The mean wheel speed ``z`` [m/s] = scale * v (1 + cos delta) / 2 (front ~v, rear
        v cos delta)."""
        xm = self._xm
        v, doff, kws = xm[IV], xm[IDOFF], xm[IKWS]
        sw = self._sw_meas if t - self._t_sw <= self._sw_age else self._u[0]
        d = self._off + self._scale * sw + doff
        c = 0.5 * (1.0 + math.cos(d))
        hm = self._hm_speed
        hm[IV] = kws * c
        hm[IKWS] = v * c
        hm[IDOFF] = -0.5 * kws * v * math.sin(d)
        self._update1(self._h_speed, z - kws * v * c, self._r_speed, "can_speed")

    def _apply(self, kind: int, t: float, p0: float, p1: float, p2: float, p3: float):
        """Apply one event at time ``t`` (``t >= self._t``); the payload meaning by kind."""
        if t > self._t:
            self._propagate_to(t)
        if kind == EVENT_TICK:
            self._u[0], self._u[1], self._u[2] = p0, p1, p2
            return True
        cfg = self.cfg
        if kind == EVENT_CAN:
            if p1 == p1:
                self._sw_meas, self._t_sw = p1, t
            if p0 == p0:
                self._speed_update(t, p0)
            if p2 == p2:
                self._yaw_update(p2, cfg.can_yaw_rate_radps, "can_yaw_rate", True)
            if p3 == p3:
                self._yaw_update(p3, cfg.wheel_yaw_rate_radps, "wheel_yaw_rate", False)
            if self._x[IV] < 0.0:
                self._x[IV] = 0.0
            return True
        if kind == EVENT_IMU:
            if p0 == p0:
                self._yaw_update(p0, cfg.imu_yaw_rate_radps, "imu_yaw_rate", True)
            if p1 == p1:
                self._a_imu, self._t_aimu = p1, t
            return True
        return self._gnss_update(p0, p1, p2, p3)

    def _gnss_update(self, gx: float, gy: float, gh: float, gv: float) -> bool:
        """A fix's position [m] (at the lever arm), heading [rad] and speed [m/s] (NaN:
        absent) as one gated update; after ``gnss_reinit_after`` rejected fixes in a row the
        filter re-initialises on GNSS. Returns True when accepted."""
        cfg = self.cfg
        m = (2 if gx == gx else 0) + (1 if gh == gh else 0) + (1 if gv == gv else 0)
        if m == 0:
            return False
        self._H[m].fill(0.0)
        H, y, R = self._Hm[m], self._ym[m], self._Rm[m]  # flat views: H[NXE * row + column]
        xm = self._xm
        i = 0
        angle_row = -1
        if gx == gx:
            lx, ly = self._lever
            c, s = math.cos(xm[IPSI]), math.sin(xm[IPSI])
            H[IX] = 1.0
            H[NXE + IY] = 1.0
            H[IPSI] = -lx * s - ly * c
            H[NXE + IPSI] = lx * c - ly * s
            y[0] = gx - (xm[IX] + lx * c - ly * s)
            y[1] = gy - (xm[IY] + lx * s + ly * c)
            R[0] = R[1] = cfg.gnss_position_m**2
            i = 2
        if gh == gh:
            H[NXE * i + IPSI] = 1.0
            y[i] = gh - xm[IPSI]
            R[i] = cfg.gnss_heading_rad**2
            angle_row = i
            i += 1
        if gv == gv:
            H[NXE * i + IV] = 1.0
            y[i] = gv - xm[IV]
            R[i] = cfg.gnss_speed_mps**2
        ok = self._update(m, "gnss", angle_row)
        if ok:
            self._gnss_rejects = 0
        else:
            self._gnss_rejects += 1
            if self._gnss_rejects >= cfg.gnss_reinit_after and gx == gx:
                self._reinit_from_gnss(gx, gy, gh)
        return ok

    def _reinit_from_gnss(self, gx: float, gy: float, gh: float) -> None:
        x, P = self._x, self._P
        rows = [IX, IY] + ([IPSI] if gh == gh else [])
        lx, ly = self._lever
        if gh == gh:
            x[IPSI] = x[IPSI] + math.remainder(gh - x[IPSI], 2 * math.pi)
        c, s = math.cos(x[IPSI]), math.sin(x[IPSI])
        x[IX], x[IY] = gx - (lx * c - ly * s), gy - (lx * s + ly * c)
        for r in rows:
            P[r, :] = 0.0
            P[:, r] = 0.0
            P[r, r] = self._init_var[r]
        self._gnss_rejects = 0
        if self._counting:
            self.stats["gnss"]["reinit"] += 1
