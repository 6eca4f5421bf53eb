"""The report's hybrid plant: kinematic bicycle (eq. 1), steering map (eq. 7), zone models (eq. 8).

State ``s = [x_m, y_m, psi_rad, v_mps]`` in local ENU (x east, y north, psi from east,
counter-clockwise), with (x, y) the front-wheel point as in eq. 1. Input
``u = [steering_wheel_angle_rad, accel_pedal_1, brake_pedal_1]``.

    road-wheel angle  delta = offset_rad + scale * steering_wheel_angle        (eq. 7)
    x' = v cos(psi + delta),  y' = v sin(psi + delta),  psi' = v sin(delta) / b (eq. 1)
    v' = offset_z + scale_z * accel_pedal - brake_scale_z * brake_pedal       (eq. 8, zone z)

This module is the ONE place where this physics is written (docs/style.md 13): the plant, the
MPC (:func:`derivative_batch`, :func:`jacobians_batch`), the CasADi NMPC
(:func:`bicycle_rates` with ``ops=casadi``), identification (the steering replay, the
longitudinal zone assignment) and ``Params.zone_for`` all call the functions below.

- **Eq. 1, 7, 8** (:func:`road_wheel_angle`, :func:`bicycle_rates`,
  :func:`bicycle_jacobian`, :func:`zone_accel`) are written with arithmetic operators and
  the ``cos``/``sin`` of a namespace argument ``ops`` (``numpy`` by default; ``math`` or
  ``casadi`` work too), so the same function serves a scalar, a numpy batch (arrays
  broadcast element-wise) and a CasADi symbol.
- **The zone rule** lives in ``models.zones`` (the parameter file needs it too); the plant
  selects zones with it.

**Opt-in extensions** (``HybridPlant(params, extensions=True)``, :class:`PlantExtensions`):
the physics ``hmpc diagnose`` adds in a parameter file's ``extensions:`` that belongs to a
prediction model (drag, rolling resistance, idle creep in eq. 8; the rack's cubic and the
understeer gradient in eq. 7; the actuator lags' time constants for the controller), on the
coefficients each was fitted with. The MPC predicts with them; a plant that stands in for
the car does not (the simulator injects its effects itself).

Above the last zone the plant uses the last zone's model and ``above_last_zone`` says so.
At standstill a negative acceleration holds the car at rest: it never rolls backwards under
the brake.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from hmpc.models.constants import G_MPS2
from hmpc.models.params import Params
from hmpc.models.zones import zone_of_speed, zone_with_hysteresis, zones_with_hysteresis

NX = 4  #: state size: x, y, psi, v
NU = 3  #: input size: steering-wheel angle, accel pedal, brake pedal
IX, IY, IPSI, IV = range(NX)
ISW, IAP, IBP = range(NU)


# ------------------------------------------------------------------ eq. 7, eq. 1, eq. 8
def road_wheel_angle(steering_wheel_angle_rad, offset_rad, scale):
    """Eq. 7: road-wheel angle [rad] from the steering-wheel angle [rad]."""
    return offset_rad + scale * steering_wheel_angle_rad


def steering_wheel_angle_for(road_wheel_angle_rad, offset_rad, scale):
    """Eq. 7 inverted: the steering-wheel angle [rad] that gives ``road_wheel_angle_rad``."""
    return (road_wheel_angle_rad - offset_rad) / scale


def heading_rate(v_mps, delta_rad, wheelbase_m, ops=np):
    """Eq. 1, psi' = v sin(delta) / b [rad/s] (b: wheelbase [m]).

    With ``v_mps`` a distance travelled [m] instead of a speed, the heading change [rad].
    ``ops``: the namespace that gives ``sin`` (numpy, math or casadi)."""
    return v_mps * ops.sin(delta_rad) / wheelbase_m


def position_rates(psi_rad, v_mps, delta_rad, ops=np):
    """Eq. 1, (x', y') = v (cos, sin)(psi + delta) [m/s] of the front-wheel point.

    With ``v_mps`` a distance travelled [m], the displacement [m]."""
    ang = psi_rad + delta_rad
    return v_mps * ops.cos(ang), v_mps * ops.sin(ang)


def bicycle_rates(psi_rad, v_mps, delta_rad, wheelbase_m, ops=np):
    """Eq. 1: (x' [m/s], y' [m/s], psi' [rad/s]) of the front-wheel point."""
    xd, yd = position_rates(psi_rad, v_mps, delta_rad, ops)
    return xd, yd, heading_rate(v_mps, delta_rad, wheelbase_m, ops)


class BicycleJacobian(NamedTuple):
    """The non-zero partial derivatives of eq. 1's (x', y', psi') with respect to the heading
    psi, the speed v and the steering input u (``delta = offset + scale * u``): floats, arrays
    or CasADi expressions, as ``ops`` computes them."""

    dx_dpsi: Any
    dx_dv: Any
    dy_dpsi: Any
    dy_dv: Any
    dpsi_dv: Any
    dx_du: Any
    dy_du: Any
    dpsi_du: Any


def bicycle_jacobian(psi_rad, v_mps, delta_rad, wheelbase_m, scale=1.0, ops=np) -> BicycleJacobian:
    """Eq. 1's Jacobian at (psi, v, delta); ``scale`` is d delta / d u (eq. 7's scale for
    the steering-wheel angle; 1.0 for the road-wheel angle itself)."""
    c, s = ops.cos(psi_rad + delta_rad), ops.sin(psi_rad + delta_rad)
    return BicycleJacobian(
        -v_mps * s,
        c,
        v_mps * c,
        s,
        ops.sin(delta_rad) / wheelbase_m,
        -v_mps * s * scale,
        v_mps * c * scale,
        v_mps * ops.cos(delta_rad) * scale / wheelbase_m,
    )


def zone_accel(offset_mps2, scale_mps2, brake_scale_mps2, accel_pedal, brake_pedal):
    """Eq. 8 with brake: v' [m/s^2] of a zone model (arrays broadcast: one zone per stage)."""
    return offset_mps2 + scale_mps2 * accel_pedal - brake_scale_mps2 * brake_pedal


def derivative_batch(
    plant: HybridPlant, X: np.ndarray, U: np.ndarray, zones: np.ndarray
) -> np.ndarray:
    """Continuous-time ds/dt for many (state, input, zone) rows at once: (n, 4)."""
    delta = road_wheel_angle(U[:, ISW], plant.offset_rad, plant.scale)
    out = np.empty_like(X)
    out[:, IX], out[:, IY], out[:, IPSI] = bicycle_rates(
        X[:, IPSI], X[:, IV], delta, plant.wheelbase_m
    )
    out[:, IV] = zone_accel(
        plant.z_offset[zones], plant.z_scale[zones], plant.z_brake[zones], U[:, IAP], U[:, IBP]
    )
    ext = plant.ext
    if ext is not None:  # opt-in physics of ``extensions:`` (PlantExtensions)
        if ext.steering:
            delta = ext.road_wheel_angle(
                U[:, ISW], X[:, IV], plant.offset_rad, plant.scale, plant.wheelbase_m
            )
            out[:, IX], out[:, IY], out[:, IPSI] = bicycle_rates(
                X[:, IPSI], X[:, IV], delta, plant.wheelbase_m
            )
        if ext.longitudinal:
            out[:, IV] += ext.accel(X[:, IV], U[:, IAP])
    return out


def jacobians_batch(
    plant: HybridPlant, X: np.ndarray, U: np.ndarray, zones: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time Jacobians for many rows at once: A = df/ds (n, 4, 4),
    B = df/du (n, 4, 3)."""
    n = len(X)
    delta = road_wheel_angle(U[:, ISW], plant.offset_rad, plant.scale)
    j = bicycle_jacobian(X[:, IPSI], X[:, IV], delta, plant.wheelbase_m, plant.scale)
    A = np.zeros((n, NX, NX))
    A[:, IX, IPSI], A[:, IX, IV] = j.dx_dpsi, j.dx_dv
    A[:, IY, IPSI], A[:, IY, IV] = j.dy_dpsi, j.dy_dv
    A[:, IPSI, IV] = j.dpsi_dv
    B = np.zeros((n, NX, NU))
    B[:, IX, ISW], B[:, IY, ISW], B[:, IPSI, ISW] = j.dx_du, j.dy_du, j.dpsi_du
    B[:, IV, IAP] = plant.z_scale[zones]
    B[:, IV, IBP] = -plant.z_brake[zones]
    if plant.ext is not None:
        _extension_jacobians(plant, X, U, A, B)
    return A, B


def _extension_jacobians(
    plant: HybridPlant, X: np.ndarray, U: np.ndarray, A: np.ndarray, B: np.ndarray
) -> None:
    """The Jacobian entries the opt-in extensions change, in place: the steering shape
    (d delta / d sw and, with understeer, d delta / d v through eq. 1) and the speed
    dependence of the resistances and the creep (the (v, v) entry)."""
    ext = plant.ext
    assert ext is not None  # called only for a plant with extensions
    v = X[:, IV]
    if ext.steering:
        b = plant.wheelbase_m
        delta = ext.road_wheel_angle(U[:, ISW], v, plant.offset_rad, plant.scale, b)
        dd_du, dd_dv = ext.road_wheel_angle_partials(U[:, ISW], v, plant.offset_rad, plant.scale, b)
        j = bicycle_jacobian(X[:, IPSI], v, delta, b, 1.0)  # d/d delta in the *_du slots
        A[:, IX, IPSI], A[:, IY, IPSI] = j.dx_dpsi, j.dy_dpsi
        A[:, IX, IV] = j.dx_dv + j.dx_du * dd_dv
        A[:, IY, IV] = j.dy_dv + j.dy_du * dd_dv
        A[:, IPSI, IV] = j.dpsi_dv + j.dpsi_du * dd_dv
        B[:, IX, ISW], B[:, IY, ISW] = j.dx_du * dd_du, j.dy_du * dd_du
        B[:, IPSI, ISW] = j.dpsi_du * dd_du
    if ext.longitudinal:
        A[:, IV, IV] = ext.accel_dv(v, U[:, IAP])


# ------------------------------------------------------- opt-in physics of ``extensions:``
#: accelerator pedal below which the idle creep acts (the catalogue: "throttle released"; the
#: ground-truth simulator's IdleCreep uses the same 0.01)
CREEP_PEDAL_MAX = 0.01
#: the catalogue ids this plant can add (the others are sensor or dead-time physics, which
#: the parameter file's keys or the controller's delay compensation carry)
PLANT_EXTENSION_IDS = (
    "aero_drag",
    "rolling_resistance",
    "idle_creep",
    "actuator_lag",
    "steering_nonlinearity",
    "understeer",
)


@dataclass(frozen=True)
class PlantExtensions:
    """Physics ``hmpc diagnose`` adds to the report's model (models/catalogue.py), as
    the plant predicts with it. All zero: none. See :func:`plant_extensions`.

    Args:
        drag_per_m: aero_drag c [1/m]: v' -= c v |v|.
        rolling_per_s: rolling_resistance r [1/s]: v' -= r v.
        creep_accel_mps2, creep_speed_mps: idle_creep a0 [m/s^2] and v_c [m/s]:
            v' += a0 max(0, 1 - v / v_c) while the accelerator pedal is below
            ``CREEP_PEDAL_MAX``.
        grade_rad: a constant road grade [rad] (uphill positive): v' -= g sin(grade). A
            parameter file's ``road_grade`` is the grade of the road it was recorded on, not of
            the road ahead, so it never sets this; a caller that knows the road (a map, a
            pitch estimate) may.
        cubic_per_rad2: steering_nonlinearity k3 [1/rad^2]: delta = offset + scale (sw + k3 sw^3).
        understeer_rad_per_mps2: understeer K [rad/(m/s^2)]: delta * b / (b + K v^2) acts.
        lag_steer_s, lag_long_s: actuator_lag tau [s] of the steering-wheel angle and of the
            pedals. The plant's state has no lag state: :meth:`HybridPlant.step` and the
            derivatives take the *lagged* (effective) inputs, which the controller simulates
            from the commands it issued (:func:`first_order_lag`).
    """

    drag_per_m: float = 0.0
    rolling_per_s: float = 0.0
    creep_accel_mps2: float = 0.0
    creep_speed_mps: float = 1.0
    grade_rad: float = 0.0
    cubic_per_rad2: float = 0.0
    understeer_rad_per_mps2: float = 0.0
    lag_steer_s: float = 0.0
    lag_long_s: float = 0.0

    @property
    def longitudinal(self) -> bool:
        """Whether v' has an extra term."""
        return bool(
            self.drag_per_m or self.rolling_per_s or self.creep_accel_mps2 or self.grade_rad
        )

    @property
    def steering(self) -> bool:
        """Whether eq. 7's road-wheel angle has another shape."""
        return bool(self.cubic_per_rad2 or self.understeer_rad_per_mps2)

    @property
    def active(self) -> bool:
        """Whether anything is added (a lag included)."""
        return self.longitudinal or self.steering or bool(self.lag_steer_s or self.lag_long_s)

    def accel(self, v_mps, accel_pedal):
        """Extra acceleration [m/s^2] (arrays broadcast): resistances, creep, grade."""
        v = np.asarray(v_mps, dtype=float)
        a = (
            -self.drag_per_m * v * np.abs(v)
            - self.rolling_per_s * v
            - G_MPS2 * math.sin(self.grade_rad)
        )
        if self.creep_accel_mps2:
            creep = self.creep_accel_mps2 * np.maximum(0.0, 1.0 - v / self.creep_speed_mps)
            a = a + np.where(np.asarray(accel_pedal) < CREEP_PEDAL_MAX, creep, 0.0)
        return a

    def accel_dv(self, v_mps, accel_pedal):
        """d(:meth:`accel`)/dv [1/s] (the creep's pedal switch has no derivative)."""
        v = np.asarray(v_mps, dtype=float)
        d = -2.0 * self.drag_per_m * np.abs(v) - self.rolling_per_s
        if self.creep_accel_mps2:
            on = (np.asarray(accel_pedal) < CREEP_PEDAL_MAX) & (v < self.creep_speed_mps)
            d = d - np.where(on, self.creep_accel_mps2 / self.creep_speed_mps, 0.0)
        return d

    def road_wheel_angle(self, sw_rad, v_mps, offset_rad, scale, wheelbase_m):
        """Road-wheel angle [rad] with the steering extensions (eq. 7 when there are none)."""
        delta = road_wheel_angle(sw_rad + self.cubic_per_rad2 * sw_rad**3, offset_rad, scale)
        if self.understeer_rad_per_mps2:
            delta = (
                delta * wheelbase_m / (wheelbase_m + self.understeer_rad_per_mps2 * v_mps * v_mps)
            )
        return delta

    def road_wheel_angle_partials(self, sw_rad, v_mps, offset_rad, scale, wheelbase_m):
        """(d delta / d sw [1], d delta / d v [rad s/m]) of :meth:`road_wheel_angle`."""
        k, b = self.understeer_rad_per_mps2, wheelbase_m
        d_sw = scale * (1.0 + 3.0 * self.cubic_per_rad2 * sw_rad**2)
        if not k:
            return d_sw, 0.0 * v_mps
        g = b / (b + k * v_mps * v_mps)
        delta0 = road_wheel_angle(sw_rad + self.cubic_per_rad2 * sw_rad**3, offset_rad, scale)
        return d_sw * g, -delta0 * g * g * 2.0 * k * v_mps / b


def first_order_lag(y, u, h_s: float, tau_s: float):
    """Exact first-order lag tau y' = u - y over ``h_s`` [s] with ``u`` held [same unit]."""
    if tau_s <= 0:
        return u
    return u + (y - u) * math.exp(-h_s / tau_s)


def _ext_value(params: Params, eid: str, sub: str, key: str) -> float:
    return float(params.extensions.get(eid, {}).get(sub, {}).get(key, 0.0) or 0.0)


def _extension_bases(params: Params, used: dict) -> tuple[dict | None, list | None]:
    """The coefficients the used extensions were fitted jointly with (``base:``): steering
    {offset_rad, scale} and longitudinal zones (only a pedal map: ``scale_mps2`` per zone,
    and the zones' names as in the file). An entry fitted on top of another
    (``on_top_of``) holds the joint fit, so it is preferred."""
    st, lon = None, None
    for sub in ("steering", "longitudinal"):
        ents = [
            params.extensions[e][sub]
            for e in used[sub]
            if "base" in params.extensions[e].get(sub, {})
        ]
        ents.sort(key=lambda e: "on_top_of" not in e)
        if not ents:
            continue
        base = ents[0]["base"]
        if sub == "steering":
            st = base
        elif [z.get("name") for z in base["zones"]] == [z.name for z in params.zones] and all(
            "scale_mps2" in z for z in base["zones"]
        ):
            lon = base["zones"]
    return st, lon


def plant_extensions(params: Params) -> tuple[PlantExtensions | None, dict | None, list | None]:
    """The physics of ``params.extensions`` a prediction model should add
    (``PLANT_EXTENSION_IDS``), and the base coefficients to use with them.

    Returns (extensions or None when there are none, steering base {offset_rad, scale} or
    None, zone bases [{name, offset_mps2, scale_mps2[, brake_scale_mps2]}] or None). When a
    longitudinal entry's base is not a pedal map (a model fitted on ``accel_cmd``), the
    longitudinal terms (drag, rolling, creep) are left out: the file's zones then hold the
    baseline's fit, which absorbs them, and adding them on top would count them twice. An
    entry without a base is taken as a term on top of the file's own keys.
    """
    x = params.extensions or {}
    used = {
        "steering": [e for e in PLANT_EXTENSION_IDS if "steering" in x.get(e, {})],
        "longitudinal": [e for e in PLANT_EXTENSION_IDS if "longitudinal" in x.get(e, {})],
    }
    st, lon = _extension_bases(params, used)
    kw = {
        "cubic_per_rad2": _ext_value(params, "steering_nonlinearity", "steering", "cubic_per_rad2"),
        "understeer_rad_per_mps2": _ext_value(
            params, "understeer", "steering", "gradient_rad_per_mps2"
        ),
        "lag_steer_s": _ext_value(params, "actuator_lag", "steering", "tau_s"),
        "lag_long_s": _ext_value(params, "actuator_lag", "longitudinal", "tau_s"),
    }
    lon_ids = used["longitudinal"]
    cmd_fit = any(
        "base" in x[e]["longitudinal"]
        and not all("scale_mps2" in z for z in x[e]["longitudinal"]["base"]["zones"])
        for e in lon_ids
    )
    if not cmd_fit:
        kw.update(
            drag_per_m=_ext_value(params, "aero_drag", "longitudinal", "coeff_per_m"),
            rolling_per_s=_ext_value(params, "rolling_resistance", "longitudinal", "coeff_per_s"),
            creep_accel_mps2=_ext_value(params, "idle_creep", "longitudinal", "accel_mps2"),
        )
        if kw["creep_accel_mps2"]:
            kw["creep_speed_mps"] = _ext_value(
                params, "idle_creep", "longitudinal", "creep_speed_mps"
            )
    ext = PlantExtensions(**kw)
    if not ext.active:
        return None, None, None
    return ext, st, lon


# ---------------------------------------------------------------------------- the plant
@dataclass
class StepResult:
    """One plant step: the new state, the zone used, and the acceleration applied [m/s^2]."""

    state: np.ndarray
    zone: int
    accel_mps2: float
    above_last_zone: bool


class HybridPlant:
    """Eq. 1 + eq. 7 + eq. 8 with zone hysteresis; see the module docstring.

    Args:
        params: a complete model (``Params.is_model``).
        hysteresis_mps: zone hysteresis h [m/s]; default ``params.hysteresis_mps`` or 0.25.
        extensions: also predict with the physics of ``params.extensions`` that belongs to
            a prediction model (:func:`plant_extensions`: drag, rolling resistance, idle
            creep, the steering map's shape; the lag time constants as ``ext``'s for the
            controller), with the steering map and zones they were fitted jointly with
            (their ``base:``). Opt-in: a plant that stands in for the car (the closed loop's
            truth, the simulator node) must not add them on top of the effects
            ``models.sim.effects`` injects. ``ext`` is None when nothing applies, and the
            plant is then the report's model exactly.
    """

    #: the opt-in extensions (:class:`PlantExtensions`), None: the report's model
    ext: PlantExtensions | None = None

    def __init__(
        self, params: Params, hysteresis_mps: float | None = None, *, extensions: bool = False
    ):
        if not params.is_model:
            raise ValueError("HybridPlant needs a parameter file with steering and zones")
        self.params = params
        self.wheelbase_m = float(params.vehicle.wheelbase_m)
        assert params.steering is not None  # is_model
        self.offset_rad = float(params.steering.offset_rad)
        self.scale = float(params.steering.scale)
        h = hysteresis_mps if hysteresis_mps is not None else params.hysteresis_mps
        self.hysteresis_mps = 0.25 if h is None else float(h)
        z = params.zones
        self.v_min = np.array([q.v_min_mps for q in z])
        self.v_max = np.array([q.v_max_mps for q in z])
        self.z_offset = np.array([q.offset_mps2 for q in z])
        self.z_scale = np.array([q.scale_mps2 for q in z])
        self.z_brake = np.array([q.brake_scale_mps2 for q in z])
        self.n_zones = len(z)
        if extensions:
            self._use_extensions(params)
        self._v_min_list = self.v_min.tolist()
        self._v_max_list = self.v_max.tolist()
        # eq. 8 per zone as Python floats for the scalar step: (offset, scale, brake scale)
        self._eq8 = list(zip(self.z_offset.tolist(), self.z_scale.tolist(), self.z_brake.tolist()))

    def _use_extensions(self, params: Params) -> None:
        """Set ``ext`` and take the base coefficients of :func:`plant_extensions`."""
        ext, st, zones = plant_extensions(params)
        self.ext = ext
        if st is not None:
            self.offset_rad = float(st.get("offset_rad", self.offset_rad))
            self.scale = float(st.get("scale", self.scale))
        if zones is not None:
            self.z_offset = np.array([b["offset_mps2"] for b in zones], dtype=float)
            self.z_scale = np.array([b["scale_mps2"] for b in zones], dtype=float)
            # a recording without braking has no brake scale in its base: the file's; so
            # too for a non-positive one (a brake that accelerates is no physics: hmpc
            # diagnose wrote the base's brake gain with its sign flipped)
            self.z_brake = np.array(
                [
                    b["brake_scale_mps2"]
                    if b.get("brake_scale_mps2", 0.0) > 0.0
                    else q.brake_scale_mps2
                    for b, q in zip(zones, params.zones)
                ],
                dtype=float,
            )

    # ----------------------------------------------------------------- zones
    def zone_by_speed(self, v_mps: float) -> int:
        """Zone whose (v_min, v_max] holds v (the first zone includes 0; last zone above all)."""
        return zone_of_speed(v_mps, self._v_max_list, clamp=True)

    def select_zone(self, v_mps: float, current: int | None) -> int:
        """Zone with hysteresis: keep ``current`` while v is within its band widened by h."""
        return zone_with_hysteresis(
            v_mps, current, self._v_min_list, self._v_max_list, self.hysteresis_mps, clamp=True
        )

    def zone_schedule(self, v_mps: np.ndarray, start: int | None) -> np.ndarray:
        """:meth:`select_zone` along a speed sequence, starting from zone ``start``."""
        return zones_with_hysteresis(
            v_mps, self._v_min_list, self._v_max_list, self.hysteresis_mps, start=start, clamp=True
        )

    # ------------------------------------------------------------- dynamics
    def road_wheel_angle(self, steering_wheel_angle_rad, v_mps=0.0):
        """Eq. 7 [rad] (with the steering extensions, at speed ``v_mps`` [m/s], if any)."""
        if self.ext is not None and self.ext.steering:
            return self.ext.road_wheel_angle(
                np.asarray(steering_wheel_angle_rad, dtype=float),
                v_mps,
                self.offset_rad,
                self.scale,
                self.wheelbase_m,
            )
        return road_wheel_angle(np.asarray(steering_wheel_angle_rad), self.offset_rad, self.scale)

    def accel(self, zone: int, accel_pedal: float, brake_pedal: float) -> float:
        """Eq. 8 with brake for ``zone`` [m/s^2]."""
        off, sc, br = self._eq8[zone]
        return float(zone_accel(off, sc, br, accel_pedal, brake_pedal))

    def derivative(self, s: np.ndarray, u: np.ndarray, zone: int) -> np.ndarray:
        """Continuous-time ds/dt (no standstill clamp): :func:`derivative_batch` of one row."""
        return derivative_batch(
            self,
            np.atleast_2d(np.asarray(s, dtype=float)),
            np.atleast_2d(np.asarray(u, dtype=float)),
            np.array([zone]),
        )[0]

    def step(
        self,
        s: np.ndarray,
        u: np.ndarray | Sequence[float],
        dt_s: float,
        zone: int | None = None,
        accel_extra_mps2: float = 0.0,
    ) -> StepResult:
        """Advance ``dt_s`` with inputs held, zone chosen with hysteresis from ``zone``.

        ``accel_extra_mps2`` adds unmodelled acceleration (drag, grade: used by the simulator
        to conceal effects). Integration: exact in speed (piecewise-constant acceleration,
        clamped at standstill), midpoint in heading and position (eq. 1 over the distance
        travelled: its rates are linear in v).
        """
        # scalar arithmetic in Python floats and math (this runs per plant step, per
        # estimator prediction and per simulator sample: numpy on scalars costs 10x more)
        x0, y0, psi0, vs = np.asarray(s, dtype=float)[:4].tolist()
        z = self.select_zone(vs, zone)
        a = self.accel(z, float(u[IAP]), float(u[IBP])) + accel_extra_mps2
        ext = self.ext
        if ext is not None:
            return self._step_extended(x0, y0, psi0, vs, u, dt_s, z, a)
        v0 = max(vs, 0.0)
        v1 = v0 + a * dt_s
        if v1 < 0.0:  # stops within the step and stays stopped: never rolls backwards
            t_move = v0 / -a if a < 0 else 0.0
            v1 = 0.0
            dist = 0.5 * v0 * t_move
            a_eff = -v0 / dt_s
        else:
            dist = 0.5 * (v0 + v1) * dt_s
            a_eff = a
        delta = road_wheel_angle(float(u[ISW]), self.offset_rad, self.scale)
        dpsi = heading_rate(dist, delta, self.wheelbase_m, ops=math)
        psi_mid = psi0 + 0.5 * dpsi
        dx, dy = position_rates(psi_mid, dist, delta, ops=math)
        out = np.array([x0 + dx, y0 + dy, psi0 + dpsi, v1])
        return StepResult(out, z, a_eff, bool(vs > self.v_max[-1]))

    def _step_extended(self, x0, y0, psi0, vs, u, dt_s, z, a) -> StepResult:
        """:meth:`step` with ``ext``: the extra acceleration at the midpoint speed of the step
        (one predictor pass: the resistances change little over a step), the steering shape
        at that speed; the same standstill rule and midpoint position update."""
        ext = self.ext
        assert ext is not None  # called only with extensions
        v0 = max(vs, 0.0)
        ap = float(u[IAP])
        if ext.longitudinal:
            a_mid = a + float(ext.accel(v0, ap))
            a = a + float(ext.accel(max(v0 + 0.5 * a_mid * dt_s, 0.0), ap))
        v1 = v0 + a * dt_s
        if v1 < 0.0:
            t_move = v0 / -a if a < 0 else 0.0
            v1, dist, a_eff = 0.0, 0.5 * v0 * t_move, -v0 / dt_s
        else:
            dist, a_eff = 0.5 * (v0 + v1) * dt_s, a
        delta = float(self.road_wheel_angle(float(u[ISW]), 0.5 * (v0 + v1)))
        dpsi = heading_rate(dist, delta, self.wheelbase_m, ops=math)
        dx, dy = position_rates(psi0 + 0.5 * dpsi, dist, delta, ops=math)
        return StepResult(
            np.array([x0 + dx, y0 + dy, psi0 + dpsi, v1]), z, a_eff, bool(vs > self.v_max[-1])
        )

    def jacobians(self, s: np.ndarray, u: np.ndarray, zone: int) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time Jacobians (A = df/ds, B = df/du) at (s, u) in ``zone``:
        :func:`jacobians_batch` of one row."""
        A, B = jacobians_batch(
            self,
            np.atleast_2d(np.asarray(s, dtype=float)),
            np.atleast_2d(np.asarray(u, dtype=float)),
            np.array([zone]),
        )
        return A[0], B[0]


class DelayLine:
    """A pure dead time on one signal, in whole steps of the loop period.

    Args:
        delay_s: dead time [s]; rounded to the nearest whole number of ``dt_s`` steps.
        dt_s: loop period [s].
        initial: value output until the first input has travelled through.
    """

    def __init__(self, delay_s: float, dt_s: float, initial: float = 0.0):
        self.n = max(int(round(delay_s / dt_s)), 0)
        self._buf = [float(initial)] * self.n

    def push(self, value: float) -> float:
        """Feed this step's input; return the input of ``n`` steps ago."""
        if self.n == 0:
            return float(value)
        self._buf.append(float(value))
        return self._buf.pop(0)

    def pending(self) -> list[float]:
        """Inputs still in flight, oldest first (what an MPC must predict through)."""
        return list(self._buf)
