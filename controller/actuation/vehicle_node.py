"""The vehicle simulator node: the fake at the boundary, on the far end of a python-can bus.

It answers the drive loop the way the car (or the by-wire kit) does, through frames only:

- it receives the command frames and checks them as an ECU would: length, checksum/CRC and
  rolling counter (the next value, modulo its range); a bad frame is ignored and counted
  (``rejected`` by reason);
- it runs the hybrid plant (``models.plant.HybridPlant``) of the *truth* parameters, optionally
  with the ground-truth simulator's concealed effects (``models.sim.effects``), in real time;
- it publishes the feedback messages of the profile's DBC at the car's rates (Toyota: measured
  in the bundled comma2k19 minute) with the EPS torque and the status bits;
- it faults the way the car does: a command that breaks the car's own limits (modelled here,
  set above the panda's so that a frame the panda allows never faults the car) puts the EPS in
  ``temporary_fault`` (Toyota) or the kit in ``FAULT`` for one second and is not applied;
  a command stream that stops (no frame for 5 of its periods) is dropped (EPS standby,
  ACC coasting, the kit disengages after 3 missed heartbeats).

Toyota actuators (modelled, not identified; document of the tuning in ``drive.py``):

- EPS: the motor torque follows the accepted request [raw units] with a 20 ms lag; the steering
  wheel is J th'' = g T + T_driver - k(v) th - c th' (J 0.04 kg m^2, c 0.1 N m s/rad,
  k(v) = 0.3 + 0.004 v^2 N m/rad, the self-aligning stiffness felt at the wheel; g 0.005 N m per
  unit, so 1500 units = 7.5 N m), clamped at the lock;
- ACC: the acceleration request passes a 0.25 s first-order powertrain lag and the car's own
  inversion of the zone model (eq. 8 of the *truth* parameters) into pedal and brake.

By-wire kit: the steering servo follows the angle command with a 50 ms lag and at most
2 pi rad/s; pedals are applied as commanded. Before the kit first engages, the simulated
safety driver holds the speed (as the Toyota's own cruise control does before openpilot
takes over).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import can
import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant
from hmpc.models.sim.sensors import wheel_speeds

from hmpc.controller.actuation.checksums import SCHEMES
from hmpc.controller.actuation.profiles import ActuationProfile

#: feedback message -> rate [Hz] the node publishes at. Toyota: frames per second of each id in
#: the bundled comma2k19 minute (0x0AA 4974 frames / 60 s, 0x260 3000, 0x262 1499, 0x1D2 1890,
#: 0x224 2487, 0x2C1 1890, 0x3BC about 1 Hz).
TOYOTA_RATES_HZ = {
    "WHEEL_SPEEDS": 83.3,
    "STEER_ANGLE_SENSOR": 83.3,
    "KINEMATICS": 83.3,
    "STEER_TORQUE_SENSOR": 50.0,
    "EPS_STATUS": 25.0,
    "PCM_CRUISE": 31.5,
    "BRAKE_MODULE": 41.4,
    "GAS_PEDAL": 31.5,
    "GEAR_PACKET": 1.0,
}
#: the by-wire kit's report rates (its DBC's comments)
BYWIRE_RATES_HZ = {
    "BW_STEER_REPORT": 100.0,
    "BW_PEDAL_REPORT": 50.0,
    "BW_WHEEL_SPEEDS": 50.0,
    "BW_STATUS": 10.0,
}

# The car's own limits (modelled): above panda's so that allowed frames never fault the car.
EPS_MAX_TORQUE = 1800  # raw units; panda allows 1500
EPS_MAX_STEP = 100  # raw units per frame, rising; panda allows 15 up (any drop to 0)
ACC_MIN_MPS2, ACC_MAX_MPS2 = -5.0, 3.0  # panda allows -3.5 .. 2.0
FAULT_S = 1.0  # a fault lasts this long [s]
KIT_RATE_MAX_RADPS = 2 * math.pi
# steering column (Toyota node): J th'' = G_EPS T + T_driver - (K0 + K2 v^2) th - C_COL th'
J_COL = 0.04  # kg m^2, wheel + column + motor inertia at the wheel
C_COL = 0.1  # N m s/rad, column damping
K0, K2 = 0.3, 0.004  # N m/rad and N m s^2/(rad m^2): self-aligning stiffness felt at the wheel
G_EPS = 0.005  # N m per raw torque unit at the wheel (1500 units = 7.5 N m)
KIT_ANGLE_MAX_RAD = 2.5 * math.pi


@dataclass
class NodeStats:
    accepted: dict = field(default_factory=dict)
    rejected: dict = field(default_factory=dict)
    faults: list = field(default_factory=list)
    published: dict = field(default_factory=dict)
    # longest interval between two publications of a message [s]: a simulator thread the host
    # starved (a gap of several periods) tells a test that a ``feedback_loss`` stop was the
    # simulated car's silence, which the loop is right to stop on, not a loop defect
    max_gap_s: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "accepted": dict(self.accepted),
            "rejected": dict(self.rejected),
            "rejected_total": int(sum(self.rejected.values())),
            "faults": [{"t_s": round(t, 4), "what": w} for t, w in self.faults],
            "published": dict(self.published),
            "max_gap_s": {k: round(v, 4) for k, v in self.max_gap_s.items()},
        }


class VehicleNode:
    """A simulated car on a CAN bus (see the module docstring).

    Args:
        profile: the actuation profile (its DBC, commands and checksum schemes).
        truth: the parameters of the simulated car (eq. 1, 7, 8).
        bus_kwargs: ``can.Bus`` arguments, e.g. ``{"interface": "virtual", "channel": "x"}``.
        start_state: plant state [x, y, psi, v] (local ENU, m, m, rad, m/s).
        effects: concealed effects (``models.sim.effects.Effect``) applied to the plant.
        tick_s: the node's internal step [s].
    """

    def __init__(
        self,
        profile: ActuationProfile,
        truth: Params,
        bus_kwargs: dict,
        *,
        start_state=None,
        effects=(),
        tick_s: float = 0.004,
    ):
        self.profile = profile
        self.plant = HybridPlant(truth)
        self.truth = truth
        self.bus_kwargs = dict(bus_kwargs)
        self.tick_s = float(tick_s)
        self.effects = list(effects)
        for e in self.effects:
            e.start(self.tick_s, truth)
        self.state = np.zeros(4) if start_state is None else np.array(start_state, float)
        self.zone = self.plant.select_zone(float(self.state[3]), None)
        self.stats = NodeStats()
        self.toyota = profile.steering == "torque"
        self.rates = TOYOTA_RATES_HZ if self.toyota else BYWIRE_RATES_HZ
        self._msgs = {n: profile.db.get_message_by_name(n) for n in self.rates}
        self._by_id = {c.message.frame_id: c for c in profile.commands.values()}
        self._last_counter: dict[int, int] = {}
        self._last_rx_s: dict[int, float] = {}
        self._pub_counter = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.t0: float | None = None
        # actuator state
        self.sw_rad = 0.0  # steering-wheel angle
        self.sw_rate = 0.0
        self.eps_torque = 0.0  # motor torque [raw command units]
        self.torque_req = 0.0
        self.steer_req = False
        self.last_torque_frame = 0.0
        self.accel_req = 0.0
        self.accel_filt = 0.0
        self.angle_cmd = 0.0
        self.steer_enable = False
        self.pedal_cmd = (0.0, 0.0)
        self.pedal_enable = False
        self.engaged = False  # kit engaged (heartbeat)
        self.cruise_active = True  # the driver engaged cruise before the run (Toyota)
        self.fault_until = -1.0
        self.reject_until = -1.0
        self.driver_torque_until = -1.0
        self.driver_torque = 0.0
        self.ap = self.bp = 0.0
        self.accel_mps2 = 0.0

    # ------------------------------------------------------------------ control
    def start(self, t0: float | None = None) -> None:
        self.t0 = time.monotonic() if t0 is None else t0
        self._bus: can.BusABC | None = can.Bus(**self.bus_kwargs)
        self._thread = threading.Thread(target=self._run, name="vehicle-node", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if getattr(self, "_bus", None) is not None:
            assert self._bus is not None
            self._bus.shutdown()
            self._bus = None

    def now(self) -> float:
        assert self.t0 is not None  # started
        return time.monotonic() - self.t0

    def reject_commands(self, t_s: float, duration_s: float = 0.3) -> None:
        """Fault injection (``vehicle_rejects``): from ``t_s`` the car's ECUs refuse every
        command for ``duration_s`` and say so in their status bits."""
        with self._lock:
            self.reject_until = -(t_s + duration_s)  # negative: armed, not yet active
            self._reject_from = t_s

    def driver_steers(self, t_s: float, duration_s: float = 1.0) -> None:
        """Fault injection (``driver_override``): the driver holds the wheel from ``t_s``."""
        with self._lock:
            self._driver_from = t_s
            self._driver_for = duration_s

    def snapshot(self) -> dict:
        with self._lock:
            return {
                "state": self.state.copy(),
                "sw_rad": self.sw_rad,
                "ap": self.ap,
                "bp": self.bp,
                "accel_mps2": self.accel_mps2,
            }

    # ------------------------------------------------------------------- thread
    def _run(self) -> None:
        due = {n: 0.0 for n in self.rates}
        last_pub: dict = {}
        t_prev = self.now()
        nxt = t_prev
        while not self._stop.is_set():
            nxt += self.tick_s
            delay = nxt - self.now()
            if delay > 0:
                time.sleep(delay)
            t = self.now()
            if t - nxt > 0.1:  # we were descheduled for long: do not try to catch up
                nxt = t
            assert self._bus is not None  # open until the thread has stopped
            while True:
                msg = self._bus.recv(timeout=0.0)
                if msg is None:
                    break
                self._receive(msg, t)
            dt = min(max(t - t_prev, 0.0), 0.05)
            t_prev = t
            with self._lock:
                self._step(t, dt)
            for name, rate in self.rates.items():
                if t >= due[name]:
                    due[name] = max(due[name] + 1.0 / rate, t)
                    try:
                        self._bus.send(self._feedback(name, t))
                        self.stats.published[name] = self.stats.published.get(name, 0) + 1
                        if name in last_pub:
                            self.stats.max_gap_s[name] = max(
                                self.stats.max_gap_s.get(name, 0.0), t - last_pub[name]
                            )
                        last_pub[name] = t
                    except can.CanError:
                        pass

    # ---------------------------------------------------------------- receiving
    def _reject(self, reason: str) -> None:
        self.stats.rejected[reason] = self.stats.rejected.get(reason, 0) + 1

    def _receive(self, msg: can.Message, t: float) -> None:
        spec = self._by_id.get(msg.arbitration_id)
        if spec is None or msg.is_extended_id:
            return
        m = spec.message
        data = bytes(msg.data)
        if len(data) != m.length:
            return self._reject("length")
        if (
            spec.checksum is not None
            and spec.scheme is not None
            and SCHEMES[spec.scheme](m.frame_id, data) != data[-1]
        ):
            return self._reject("checksum")
        raw = m.decode(data, decode_choices=False, scaling=False)
        if spec.counter is not None:
            c = int(raw[spec.counter])
            last = self._last_counter.get(m.frame_id)
            fresh = last is None or t - self._last_rx_s.get(m.frame_id, -1e9) > 0.5
            self._last_counter[m.frame_id] = c
            self._last_rx_s[m.frame_id] = t
            if not fresh and last is not None and c != (last + 1) % spec.counter_modulo:
                return self._reject("counter")
        with self._lock:
            if self._rejecting(t):
                return self._reject("ecu_not_accepting")
            ok = self._apply(spec, raw, t)
        if ok:
            self.stats.accepted[m.name] = self.stats.accepted.get(m.name, 0) + 1
        else:
            self._reject("car_limit")

    def _rejecting(self, t: float) -> bool:
        if self.reject_until < 0 and t >= getattr(self, "_reject_from", math.inf):
            self.reject_until = -self.reject_until
            self.stats.faults.append((t, "ecu rejects commands (injected)"))
        return t < self.reject_until

    def _fault(self, t: float, what: str) -> bool:
        self.fault_until = t + FAULT_S
        self.stats.faults.append((t, what))
        return False

    def _apply(self, spec, raw: dict, t: float) -> bool:
        """Take an accepted command frame; False (and a fault) when it breaks the car's limits."""
        sig = spec.values
        if spec.role == "steer_torque":
            tq = float(raw[sig["steer_torque"]])
            req = bool(raw[spec.enable[0]]) if spec.enable else True
            if t < self.fault_until:
                self.torque_req, self.steer_req = 0.0, False
                return True
            rising = abs(tq) > abs(self.torque_req) and abs(tq - self.torque_req) > EPS_MAX_STEP
            if req and (abs(tq) > EPS_MAX_TORQUE or rising):
                self.torque_req, self.steer_req = 0.0, False
                return self._fault(t, f"EPS: torque {tq:.0f} beyond the EPS limits")
            self.torque_req, self.steer_req = (tq if req else 0.0), req
            self.last_torque_frame = t
        elif spec.role == "accel":
            a = (
                float(raw[sig["accel_mps2"]])
                * spec.message.get_signal_by_name(sig["accel_mps2"]).scale
            )
            if not ACC_MIN_MPS2 <= a <= ACC_MAX_MPS2:
                self.accel_req = 0.0
                return self._fault(t, f"ACC: request {a:.2f} m/s^2 beyond the car's limits")
            self.accel_req = a
            self._last_accel_frame = t
        elif spec.role == "steer_angle":
            s = spec.message.get_signal_by_name(sig["steering_wheel_angle_rad"])
            ang = float(raw[sig["steering_wheel_angle_rad"]]) * s.scale
            self.steer_enable = bool(raw[spec.enable[0]])
            if abs(ang) > KIT_ANGLE_MAX_RAD:
                self.steer_enable = False
                return self._fault(t, f"kit: angle {ang:.2f} rad beyond lock")
            self.angle_cmd = ang
            self._last_steer_frame = t
        elif spec.role == "pedals":
            sa = spec.message.get_signal_by_name(sig["accel_pedal"]).scale
            sb = spec.message.get_signal_by_name(sig["brake_pedal"]).scale
            ap = float(raw[sig["accel_pedal"]]) * sa
            bp = float(raw[sig["brake_pedal"]]) * sb
            self.pedal_enable = all(bool(raw[e]) for e in spec.enable)
            if ap > 1e-3 and bp > 1e-3 or ap > 1.0 or bp > 1.0:
                self.pedal_cmd = (0.0, self.pedal_cmd[1])
                return self._fault(t, "kit: throttle with brake / pedal beyond travel")
            self.pedal_cmd = (ap, bp)
            self._last_pedal_frame = t
        elif spec.role == "heartbeat":
            self.engaged = bool(raw[spec.enable[0]]) if spec.enable else True
            self._last_heartbeat = t
        return True

    # ----------------------------------------------------------------- dynamics
    def _step(self, t: float, dt: float) -> None:
        if dt <= 0:
            return
        v = float(self.state[3])
        # scripted driver (fault injection)
        df = getattr(self, "_driver_from", None)
        self.driver_torque = 0.0
        if df is not None and df <= t < df + self._driver_for:
            self.driver_torque = 1.0
        if self.toyota:
            sw, ap, bp = self._toyota_actuators(t, dt, v)
        else:
            sw, ap, bp = self._kit_actuators(t, dt)
        for e in self.effects:
            sw = e.steering(sw, v)
            ap, bp = e.pedals(ap, bp)
        extra = sum(e.accel_extra_mps2(self.state, (sw, ap, bp)) for e in self.effects)
        r = self.plant.step(self.state, np.array([sw, ap, bp]), dt, self.zone, extra)
        self.state, self.zone, self.accel_mps2 = r.state, r.zone, r.accel_mps2
        self.ap, self.bp = ap, bp

    def _toyota_actuators(self, t: float, dt: float, v: float):
        active = (
            self.steer_req
            and t < self.last_torque_frame + 0.05
            and t >= self.fault_until
            and not self._rejecting(t)
        )
        target = self.torque_req if active else 0.0
        self.eps_torque += (target - self.eps_torque) * min(dt / 0.02, 1.0)
        k = K0 + K2 * v * v
        t_drv = 3.0 * self.driver_torque * (-np.sign(self.sw_rad) if self.sw_rad else 1.0)
        acc = (G_EPS * self.eps_torque + t_drv - k * self.sw_rad - C_COL * self.sw_rate) / J_COL
        # semi-implicit Euler in small steps (stiff at speed)
        n = max(int(math.ceil(dt / 0.001)), 1)
        h = dt / n
        for _ in range(n):
            acc = (G_EPS * self.eps_torque + t_drv - k * self.sw_rad - C_COL * self.sw_rate) / J_COL
            self.sw_rate += acc * h
            self.sw_rad += self.sw_rate * h
        lock = KIT_ANGLE_MAX_RAD
        if abs(self.sw_rad) > lock:
            self.sw_rad = math.copysign(lock, self.sw_rad)
            self.sw_rate = 0.0
        long_ok = (
            self.cruise_active
            and t < getattr(self, "_last_accel_frame", -1) + 0.15
            and not self._rejecting(t)
        )
        a_req = self.accel_req if long_ok else 0.0
        self.accel_filt += (a_req - self.accel_filt) * min(dt / 0.25, 1.0)
        if not long_ok:
            return self.sw_rad, 0.0, 0.0
        return (self.sw_rad,) + self._pedals_for(self.accel_filt, v)

    def _kit_actuators(self, t: float, dt: float):
        hb_ok = t < getattr(self, "_last_heartbeat", -1) + 0.3  # 3 missed 10 Hz heartbeats
        ok = self.engaged and hb_ok and t >= self.fault_until and not self._rejecting(t)
        if ok and self.steer_enable and t < getattr(self, "_last_steer_frame", -1) + 0.05:
            err = self.angle_cmd - self.sw_rad
            step = err * min(dt / 0.05, 1.0)
            lim = KIT_RATE_MAX_RADPS * dt
            self.sw_rad += min(max(step, -lim), lim)
        if self.driver_torque:
            self.sw_rad += 0.0  # the driver holds the wheel where it is
        if ok and self.pedal_enable and t < getattr(self, "_last_pedal_frame", -1) + 0.1:
            self._handed_over = True
            return self.sw_rad, self.pedal_cmd[0], self.pedal_cmd[1]
        if not getattr(self, "_handed_over", False):
            # before the kit first engages, the safety driver holds the speed (a = 0)
            return (self.sw_rad,) + self._pedals_for(0.0, float(self.state[3]))
        return self.sw_rad, 0.0, 0.0

    def _pedals_for(self, a_mps2: float, v: float) -> tuple[float, float]:
        """The pedals that give ``a_mps2`` by the truth's zone model (eq. 8 inverted)."""
        z = self.truth.zones[self.plant.select_zone(v, self.zone)]
        if a_mps2 >= z.offset_mps2:
            ap, bp = (a_mps2 - z.offset_mps2) / z.scale_mps2, 0.0
        else:
            ap, bp = 0.0, (z.offset_mps2 - a_mps2) / z.brake_scale_mps2
        return min(max(ap, 0.0), 1.0), min(max(bp, 0.0), 1.0)

    # ---------------------------------------------------------------- feedback
    def _feedback(self, name: str, t: float) -> can.Message:
        with self._lock:
            values = self._values(name, t)
        m = self._msgs[name]
        full = {s.name: 0 for s in m.signals}
        full.update(values)
        data = bytearray(m.encode(full, scaling=True, padding=False, strict=False))
        ck = next((s for s in m.signals if s.name in ("CHECKSUM", "CRC")), None)
        if ck is not None:
            scheme = "toyota" if self.toyota else "crc8_j1850"
            data[-1] = SCHEMES[scheme](m.frame_id, data)
        return can.Message(
            arbitration_id=m.frame_id, data=bytes(data), is_extended_id=False, dlc=len(data)
        )

    def _wheels(self, v_front: float, scale: float) -> dict:
        """Speeds of the four wheels of a rigid car without slip [m/s], each read ``scale``
        times (a tyre-radius error): eq. 1's point is the front-axle centre moving at
        ``v_front`` along the road-wheel angle; the wheel-centre speeds are the rigid body's
        (``models.sim.sensors.wheel_speeds``, the physics identify inverts: a front wheel
        moves at |(v cos delta -+ yaw track / 2, v sin delta)|, not v -+ yaw track / 2)."""
        delta = float(self.plant.road_wheel_angle(self.sw_rad))
        tf = float(self.truth.vehicle.track_front_m)
        tr = float(self.truth.vehicle.track_rear_m or tf)
        speeds = wheel_speeds(v_front, delta, self.plant.wheelbase_m, tf, tr)
        return {w: scale * float(x) for w, x in zip(("FL", "FR", "RL", "RR"), speeds)}

    def _values(self, name: str, t: float) -> dict:
        v = float(self.state[3])
        ws_scale = math.prod(e.wheel_speed_scale() for e in self.effects)  # tyre radius error
        deg = math.degrees(self.sw_rad)
        yaw = v * math.sin(float(self.plant.road_wheel_angle(self.sw_rad))) / self.plant.wheelbase_m
        self._pub_counter = (self._pub_counter + 1) % 16
        faulted = t < self.fault_until or self._rejecting(t)
        if name == "WHEEL_SPEEDS":
            return {f"WHEEL_SPEED_{w}": 3.6 * x for w, x in self._wheels(v, ws_scale).items()}
        if name == "STEER_ANGLE_SENSOR":
            coarse = 1.5 * round(deg / 1.5)
            frac = min(max(round((deg - coarse) / 0.1) * 0.1, -0.7), 0.7)
            return {
                "STEER_ANGLE": coarse,
                "STEER_FRACTION": frac,
                "STEER_RATE": math.degrees(self.sw_rate),
            }
        if name == "KINEMATICS":
            return {"YAW_RATE": math.degrees(yaw), "ACCEL_X": -self.accel_mps2, "ACCEL_Y": -v * yaw}
        if name == "STEER_TORQUE_SENSOR":
            drv = 300.0 * self.driver_torque
            return {
                "STEER_TORQUE_EPS": self.eps_torque / 0.73,
                "STEER_TORQUE_DRIVER": drv,
                "STEER_ANGLE": deg,
                "STEER_OVERRIDE": int(abs(drv) > 100),
            }
        if name == "EPS_STATUS":
            state = 25 if faulted else (5 if self.steer_req else 1)
            return {"LKA_STATE": state}
        if name == "PCM_CRUISE":
            act = self.cruise_active and not faulted
            return {
                "CRUISE_ACTIVE": int(act),
                "GAS_RELEASED": 1,
                "CRUISE_STATE": 8 if act else 0,
                "ACCEL_NET": self.accel_mps2,
            }
        if name == "BRAKE_MODULE":
            return {"BRAKE_PRESSED": 0}
        if name == "GAS_PEDAL":
            return {"GAS_PEDAL": 100.0 * self.ap, "GAS_RELEASED": int(self.ap < 1e-3)}
        if name == "GEAR_PACKET":
            return {"GEAR": 0}
        if name == "BW_STEER_REPORT":
            return {
                "STEER_ANGLE": self.sw_rad,
                "STEER_TORQUE_DRIVER": 3.0 * self.driver_torque,
                "STEER_ENABLED": int(self.steer_enable and self.engaged),
                "STEER_OVERRIDE": int(self.driver_torque > 0),
                "COUNTER": self._pub_counter,
            }
        if name == "BW_PEDAL_REPORT":
            return {
                "ACCEL_PEDAL": self.ap,
                "BRAKE_PEDAL": self.bp,
                "PEDALS_ENABLED": int(self.pedal_enable and self.engaged),
                "ACCEL_OVERRIDE": 0,
                "BRAKE_OVERRIDE": 0,
                "COUNTER": self._pub_counter,
            }
        if name == "BW_WHEEL_SPEEDS":
            return {f"WHEEL_SPEED_{w}": x for w, x in self._wheels(v, ws_scale).items()}
        if name == "BW_STATUS":
            return {
                "SYSTEM_READY": int(not faulted),
                "ENGAGED": int(self.engaged),
                "FAULT": int(faulted),
                "REJECTED_FRAMES": int(sum(self.stats.rejected.values())) % 256,
                "COUNTER": self._pub_counter,
            }
        raise KeyError(name)
