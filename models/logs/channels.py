"""The canonical channels of a recording (docs/conventions.md), with their units."""

from __future__ import annotations

#: channel name -> unit, in the order columns are written.
CHANNELS: dict[str, str] = {
    "time": "s",
    "steering_wheel_angle": "rad",
    "wheel_speed_fl": "m/s",
    "wheel_speed_fr": "m/s",
    "wheel_speed_rl": "m/s",
    "wheel_speed_rr": "m/s",
    "speed": "m/s",
    "accel_pedal": "1",
    "brake_pedal": "1",
    "gear": "-",
    "engine_rpm": "1/min",
    "yaw_rate": "rad/s",
    "accel_x": "m/s^2",
    "accel_y": "m/s^2",
    "x": "m",
    "y": "m",
    "z": "m",
    "heading": "rad",
    "pitch": "rad",
    "roll": "rad",
    "gps_speed": "m/s",
    "steering_cmd": "rad",
    "accel_pedal_cmd": "1",
    "brake_pedal_cmd": "1",
    "accel_cmd": "m/s^2",
    "speed_cmd": "m/s",
}

#: channels whose values are strings, not numbers.
STRING_CHANNELS = frozenset({"gear"})

#: channels that are angles (wrapped to (-pi, pi] where it applies; unwrapped before resampling).
ANGLE_CHANNELS = frozenset({"heading"})

VALID_GEARS = frozenset({"P", "R", "N", "D", "L", "B", "S"} | {str(i) for i in range(1, 10)})
