"""A vehicle stand-in for the operator link, without the drive loop: operator commands through
the controller's limits (``controller.limits.apply_limits``, the same as the MPC's) into the
hybrid plant (``models.plant.HybridPlant``).

``hmpc teleop`` hosts the receiver in the real drive loop (``controller.actuation``); this
stand-in exists so that the link, the operator station and the terminal UI can be tested end to
end on loopback. It handles pedal commands only: with a stop request, without an engaged link,
in reference mode or with the MPC in control (it has no MPC) it makes a controlled stop:
throttle released at once, brake pressed at its rate limit up to the controlled-stop
deceleration, steering held.
"""

from __future__ import annotations

import select
import time
from dataclasses import dataclass, field
from collections.abc import Callable

import numpy as np

from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.teleop.link import LinkReceiver, Mode, PollResult, StopRequest, VehicleStatus
from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant

#: brake asked for in a controlled stop; apply_limits caps it to the controlled-stop
#: deceleration of the zone in force and rate-limits the pressing
STOP_BRAKE = 1.0
#: below this speed the car counts as standing still [m/s]
STANDSTILL_MPS = 0.01


@dataclass
class SinkLog:
    """What the stand-in applied, one row per period (arrays built by ``arrays``)."""

    rows: list[tuple] = field(default_factory=list)
    columns: tuple = (
        "t_s",
        "x_m",
        "y_m",
        "psi_rad",
        "v_mps",
        "zone",
        "steering_wheel_angle_rad",
        "accel_pedal",
        "brake_pedal",
        "operator_accel_pedal",
        "stopping",
    )

    def arrays(self) -> dict[str, np.ndarray]:
        a = np.array(self.rows, dtype=float).reshape(-1, len(self.columns))
        return {c: a[:, i] for i, c in enumerate(self.columns)}


class PlantSink:
    """Operator commands -> ``apply_limits`` -> ``HybridPlant``, one ``step`` per period.

    Args:
        params: the plant's model (complete). dt_s: period [s].
        limits: default ``ActuatorLimits.from_params(params)``.
    """

    def __init__(self, params: Params, dt_s: float = 0.02, limits: ActuatorLimits | None = None):
        self.plant = HybridPlant(params)
        self.params = params
        self.dt_s = float(dt_s)
        self.limits = limits or ActuatorLimits.from_params(params)
        self.state = np.zeros(4)
        self.zone: int | None = None
        self.prev: Command | None = None
        self.target = Command(0.0, 0.0, 0.0)
        self.t_s = 0.0
        self.stop: StopRequest | None = None
        self.standstill_t_s: float | None = None
        self.log = SinkLog()

    def step(self, poll: PollResult, receiver: LinkReceiver) -> VehicleStatus:
        """Apply this period's commands (the last pedal command wins) and advance the plant."""
        for cmd in poll.commands:
            if cmd.mode == Mode.PEDALS:
                self.target = Command(*cmd.values)
        if poll.stop is not None:
            self.stop, self.standstill_t_s = poll.stop, None
        stopping = receiver.stop is not None or not receiver.engaged or receiver.mpc_in_control
        if stopping:
            held = self.prev.steering_wheel_angle_rad if self.prev else 0.0
            want = Command(held, 0.0, STOP_BRAKE)
        else:
            want = self.target
        z = self.plant.select_zone(float(self.state[3]), self.zone)
        u = apply_limits(
            want, self.prev, self.limits, self.dt_s, self.params.zones[z], controlled_stop=stopping
        )
        res = self.plant.step(self.state, u.as_tuple(), self.dt_s, self.zone)
        self.log.rows.append(
            (
                self.t_s,
                *self.state,
                res.zone,
                *u.as_tuple(),
                self.target.accel_pedal,
                float(stopping),
            )
        )
        self.state, self.zone, self.prev = res.state, res.zone, u
        self.t_s += self.dt_s
        if stopping and self.standstill_t_s is None and self.state[3] <= STANDSTILL_MPS:
            self.standstill_t_s = self.t_s
        return self.status()

    def status(self) -> VehicleStatus:
        v = float(self.state[3])
        p = self.prev or Command(0.0, 0.0, 0.0)
        if p.brake_pedal > 0:
            pedal = "hold" if v <= STANDSTILL_MPS else "brake"
        elif p.accel_pedal > 0:
            pedal = "throttle"
        else:
            pedal = "coast"
        z = -1 if self.zone is None else int(self.zone)
        return VehicleStatus(
            v, p.steering_wheel_angle_rad, z, self.params.zones[z].name if z >= 0 else "", pedal
        )


def serve(
    receiver: LinkReceiver,
    sink: PlantSink,
    *,
    until: Callable[[], bool],
    telemetry_every: int = 5,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> int:
    """Run the stand-in in real time: poll, step, telemetry every ``telemetry_every`` periods
    (10 Hz at 50 Hz), until ``until()``; returns the number of periods run."""
    period = sink.dt_s
    t0 = clock()
    k = 0
    while not until():
        res = receiver.poll()
        status = sink.step(res, receiver)
        if k % telemetry_every == 0:
            receiver.send_telemetry(status)
        k += 1
        next_t = t0 + k * period
        now = clock()
        if now > next_t + period:
            k = int((now - t0) / period)
            next_t = t0 + k * period
        sleep(max(next_t - clock(), 0.0))
    return k


def lockstep_vehicle(
    receiver: LinkReceiver,
    sink: PlantSink,
    sim_clock,
    telemetry_every: int = 5,
    wait_s: float = 2.0,
) -> Callable[[float], None]:
    """A ``sleep`` for ``operator.run_operator`` that runs the vehicle side in simulated time.

    Each call waits until the operator's packet of the period is readable (real loopback
    UDP), advances ``sim_clock`` by the requested time, polls the receiver and steps the sink.
    The operator and the vehicle then share one simulated clock, so a 2-minute experiment
    runs in a fraction of a second with every packet going through the real link.
    """
    count = [0]

    def sleep(dt_s: float) -> None:
        select.select([receiver], [], [], wait_s)
        sim_clock.advance(max(dt_s, 0.0))
        res = receiver.poll()
        status = sink.step(res, receiver)
        if count[0] % telemetry_every == 0:
            receiver.send_telemetry(status)
        count[0] += 1

    return sleep
