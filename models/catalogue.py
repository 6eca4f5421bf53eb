"""The catalogue of physically named hypotheses: what ``hmpc diagnose`` tests, and what the
``extensions:`` section of a parameter file may hold (``models.params`` validates that section
against it, ``models.plant`` simulates it). Its ids are part of hmpc's contract
(docs/conventions.md, "Diagnosis catalogue"); each entry names its physics, the equation
it adds to the report's model, and its parameters with units and bounds.
"""

from __future__ import annotations

CATALOGUE: dict[str, dict] = {
    "actuator_delay": {
        "physics": "dead time per subsystem",
        "equation": {
            "steering": "delta(t) = offset + scale * sw(t - d)",
            "longitudinal": "dv/dt = offset_z + gain_z * u(t - d)",
        },
        "parameters": {"delay_s": "dead time d [s], 0..1"},
    },
    "actuator_lag": {
        "physics": "first-order lag",
        "equation": {
            "steering": "tau d(sw_eff)/dt = sw - sw_eff,  delta = offset + scale * sw_eff",
            "longitudinal": "tau d(u_eff)/dt = u - u_eff,  dv/dt = offset_z + gain_z * u_eff",
        },
        "parameters": {"tau_s": "time constant tau [s], 0..1"},
    },
    "steering_nonlinearity": {
        "physics": "rack saturation at large angles",
        "equation": {"steering": "delta = offset + scale * (sw + k3 * sw^3)"},
        "parameters": {
            "cubic_per_rad2": "k3 [1/rad^2] (negative: the rack saturates), -0.02..0.02"
        },
    },
    "understeer": {
        "physics": "speed- or lateral-acceleration-dependent steering gain",
        "equation": {"steering": "psi' = v_rear tan(delta / (1 + K v^2 / b)) / b"},
        "parameters": {"gradient_rad_per_mps2": "understeer gradient K [rad/(m/s^2)], 0..0.02"},
    },
    "aero_drag": {
        "physics": "v^2 deceleration",
        "equation": {"longitudinal": "dv/dt = eq. 8 - c * v^2"},
        "parameters": {"coeff_per_m": "c = rho Cd A / (2 m) [1/m], 0..5e-3"},
    },
    "rolling_resistance": {
        "physics": "constant plus v-proportional resistance",
        "equation": {"longitudinal": "dv/dt = eq. 8 - r * v   (the constant part is in offset_z)"},
        "parameters": {"coeff_per_s": "r [1/s], 0..0.01"},
    },
    "road_grade": {
        "physics": "gravity along the road, from altitude, pitch, or accelerometer against dv/dt",
        "equation": {
            "longitudinal": "dv/dt = eq. 8 - k * g * (sin(theta) - F[sin(theta)]),  "
            "theta = asin(dz/ds),  F = 1 / (s / comp_rate + 1) "
            "(F = 0 when the pedal drives)"
        },
        "parameters": {
            "gain": "k [1] (1: the measured grade acts in full), 0..2",
            "comp_rate_per_s": "rate 1/T [1/s] at which a car driven by an "
            "acceleration request (ACC) compensates the grade "
            "itself: the grade acts as g (sin theta - F(sin theta)), "
            "F = 1 / (T s + 1); 0..1, 0 = not compensated "
            "(pedal-driven cars)",
            "grade_rms_rad": "rms measured grade [rad]",
            "grade_mean_rad": "mean measured grade [rad]",
        },
    },
    "idle_creep": {
        "physics": "speed-regulating idle torque",
        "equation": {
            "longitudinal": "dv/dt = eq. 8 + a0 * max(0, 1 - v / v_c) with the throttle released"
        },
        "parameters": {
            "accel_mps2": "creep acceleration at rest a0 [m/s^2], 0..2",
            "creep_speed_mps": "creep speed v_c [m/s], 0.5..5",
        },
    },
    "wheel_radius_error": {
        "physics": "wheel speed against GNSS",
        "equation": {"longitudinal": "speed_CAN = k * gps_speed"},
        "parameters": {"scale": "k [1] (wheel-speed reading per true speed), 0.9..1.1"},
    },
    "sensor_time_offset": {
        "physics": "a clock offset between sources",
        "equation": {"longitudinal": "speed_CAN(t) = gps_speed(t - c)"},
        "parameters": {"offset_s": "CAN clock minus INS clock c [s], -1..1"},
    },
    "wheel_speed_scale": {
        "physics": "per-side effective rolling radius, or the effective track width under load",
        "equation": {
            "steering": "(v_right - v_left) / T = rho * (r - r0) + eps * v / T  "
            "(r the gyro's yaw rate, r0 its bias, T the geometry's track)"
        },
        "parameters": {
            "track_scale": "rho = effective track width / the geometry's track [1] "
            "(the contact patches move under load), 0.8..1.2",
            "side_ratio": "eps = right / left wheel-speed reading at equal speed - "
            "1 [1] (a per-side rolling-radius difference), -0.05..0.05",
        },
    },
    "accelerometer_lag": {
        "physics": "an accelerometer's filter lag against the speed",
        "equation": {
            "longitudinal": "tau d(a_m)/dt = k * dv/dt - a_m + c  (a_m: accel_x "
            "as the sensor reports it)"
        },
        "parameters": {
            "tau_s": "filter time constant tau [s], 0..1",
            "gain": "k [1] (accel_x per true acceleration)",
        },
    },
    "sensor_mounting": {
        "physics": "an IMU or GNSS antenna mounted rotated or offset from where the geometry says",
        "equation": {
            "longitudinal": "accel_x = k * (cos(psi) * dv/dt + sin(psi) * v * r) + c  "
            "(the IMU turned by psi about the vertical axis)"
        },
        "parameters": {
            "yaw_rad": "psi: the IMU's x axis from the body's x axis, counter-"
            "clockwise seen from above [rad], -pi..pi",
            "gain": "k [1] (accel_x per true acceleration along its axis)",
        },
    },
    "gears": {
        "physics": "pedal gain and engine braking per gear (a stepped transmission)",
        "equation": {
            "longitudinal": "dv/dt = offset_g + gain_g * u + e_g * rpm_released, g the "
            "gear at each sample (recorded, or engine_rpm / v "
            "clustered into gears), rpm_released the engine speed "
            "[1000 1/min] with the accelerator released (1 without "
            "engine_rpm)"
        },
        "parameters": {
            "n_gears": "gears told apart in the recording [1], 2..9",
            "gain_ratio": "largest / smallest accelerator gain over the gears [1]",
            "engine_braking_spread_mps2": "largest - smallest released-pedal "
            "deceleration over the gears [m/s^2]",
        },
    },
    "unobserved_braking": {
        "physics": "deceleration no recorded input explains (a brake the recording lacks)",
        "equation": {
            "longitudinal": "dv/dt = eq. 8 - b(t),  0 <= b <= mu * g, b > 0 only in "
            "windows with the accelerator released (one level each)"
        },
        "parameters": {
            "mu": "friction coefficient bounding b [1] (stated, not fitted)",
            "max_decel_mps2": "largest window level of b [m/s^2], 0..mu g",
            "mean_decel_mps2": "mean window level of b [m/s^2]",
            "braking_s": "total duration of the windows [s]",
            "n_windows": "braking windows found [1]",
        },
    },
    "actuator_saturation": {
        "physics": "the command asks for more than the actuator delivers",
        "equation": {
            "longitudinal": "dv/dt = offset_z + gain_z * clip(u, -s, s),  u = accel_cmd "
            "or speed_cmd(t - d) - v"
        },
        "parameters": {
            "sat_level": "s [unit of the command's regressor: m/s^2 for accel_cmd, "
            "m/s of speed error for speed_cmd], > 0",
            "accel_mps2": "the acceleration at saturation, s times the mean gain "
            "over the fitted zones [m/s^2]",
        },
    },
}

#: text keys an ``extensions:`` entry of a parameter file may carry beside the parameters
#: (models.params validates the section against this catalogue)
EXTENSION_TEXT_KEYS = ("equation", "input", "on_top_of", "grade_source", "note")

#: hypotheses that describe the same mismatch in two ways: only the better one is a finding
#: (the steering-map shapes too: both change the gain, one with angle, one with speed, and
#: the report's experiments steer hardest at low speed; joint presence is not tested)
ALTERNATIVES = (
    {"actuator_delay", "actuator_lag"},
    {"aero_drag", "rolling_resistance"},
    {"steering_nonlinearity", "understeer"},
)
