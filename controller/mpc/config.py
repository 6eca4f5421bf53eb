"""MPC tuning: :class:`MpcConfig`, each weight and limit of the fast path (and the NMPC, which
solves the same problem) with its unit and reason.

Weights are per second of horizon (tracking) or per change (effort), so the balance does not
move when ``dt_s`` changes. ``__post_init__`` checks the report's ordering (section VI:
velocity effort above steering effort, also for the smoothness terms).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MpcConfig:
    """MPC tuning. Weights are per second of horizon (tracking) or per change (effort), so
    the balance does not move when ``dt_s`` changes."""

    horizon_s: float = 10.0  # horizon length: 10-15 s
    dt_s: float = 0.2  # QP stage length: 0.1 or 0.2 s
    # tracking
    # per m^2 of lateral error, per s. The lateral loop's bandwidth: the estimate's position
    # error (about 1 cm RMS at the default sensors, correlated over seconds) is followed
    # by the car at the loop's bandwidth, and the steering that takes grows with it (with
    # noise-free sensors a straight run has no steering reversal; with them, a car whose
    # steering gain exceeds the model's, the loop's margin smaller, wanders the wheel by
    # +-1 deg at 8 m/s to follow mm of estimate error). 2 keeps the tracking at a few cm
    # (tests/controller/test_smooth_control.py, docs/results.md)
    w_lateral: float = 2.0
    w_heading: float = 4.0  # per rad^2 of heading error, per s
    w_speed: float = 10.0  # per (m/s)^2 of speed error, per s
    # effort on the change of an input per stage, normalised to its range (steering-wheel
    # angle / its max, pedals as fractions). Report VI: velocity effort above steering.
    w_speed_effort: float = 4.0
    w_steer_effort: float = 1.0
    # smoothness, separate from tracking: the effort weights above are the RATE
    # terms (a change per stage is the rate times dt: w * (du/range/dt)^2 * dt per stage);
    # these weight the change of that rate, per (normalised rate change per s)^2 per s
    # (second differences: w * (d2u/range/dt^2)^2 * dt per stage). A reversal of the
    # command is a large second difference, a steady ramp (a curve coming) none, so they
    # damp the chatter that estimate noise causes without holding back a planned turn.
    # Velocity above steering here too (report VI). Tuned at the default sensor noise
    # (estimate noise about 1 cm, 1 mrad, 0.02 m/s) on report_2008; checked on a parameter
    # set not used for tuning (tests/controller/test_smooth_control.py holds the figures).
    w_steer_rate_change: float = 0.3
    w_pedal_rate_change: float = 1.0
    # the standstill HOLD brake is reached at this rate [full travel / s] from the brake the
    # plan already had on (the car is already stopping; a step jolts it and the pedal)
    hold_brake_rate_ps: float = 0.25
    # path sharpness: the steering-wheel rate per metre driven, (d sw / ds)^2 = (d sw/dt)^2
    # / v^2, normalised like the effort, per s. Noise in the estimate (1 cm, 1 mrad) asks
    # for a steering correction that grows as 1 / v^2 (a lateral offset y is undone over a
    # time T with a road-wheel angle of about 2 b y / (v T)^2): without this the wheel
    # chases 1 cm of estimate noise by several degrees at 1 m/s. At speed it fades (8 m/s:
    # 1/64 of its 1 m/s weight). Below the floor speed the weight stops growing [m/s].
    w_steer_sharpness: float = 100.0
    steer_sharpness_speed_floor_mps: float = 0.5
    # the UNPLANNED part of the rate: each step the inputs of the first ``replan_window_s``
    # cost their squared distance from the previous plan (shifted to now), normalised like
    # the effort, per s. A turn the reference announced is in that plan and passes freely;
    # what a new estimate adds (noise, 1 cm / 1 mrad) is low-pass filtered step to step.
    # Pedals above steering (report VI).
    w_steer_replan: float = 3000.0
    w_pedal_replan: float = 6000.0
    # The pedals' weight holds over the window; the steering's fades as a raised cosine to 0
    # at twice the window (half weight at the window, the same sum; cost.replan_fade): a
    # weight ending in a step bends every steering plan just past it, and the bend reaches
    # the wheel as a reversal a few steps later
    replan_window_s: float = 1.0
    w_pedal_level: float = 0.02  # per pedal^2 per s: prefer the lighter pedal
    # offset-free steering (``MpcController.use_steering_correction``): the estimator's
    # correction to eq. 7's road-wheel angle (the EKF's ``delta_offset_rad``), low-passed
    # with this time constant [s], is added to the model's steering offset; 0: off. It is
    # taken in only while the car steers straight (the last command's road-wheel angle,
    # by the model, within ``steer_correction_gate_rad``): there a steering-scale error does
    # not enter the correction, which on a curve would read a scale error as an offset. A
    # file whose straight-ahead is 10 deg of steering wheel off otherwise drives a straight
    # road 0.25 m off the path, met by a loop without integral action: on ramp_sequence,
    # hidden sets 1-16 without learning, steering reversals >= 1 deg 3.9-15.5 a minute
    # without it, 3.9-9.7 with it, figure8's lateral RMS within 5 % either way
    # (tools/adaptation_figures.py). With a learner (``--adapt``) the loops do not feed it:
    # the learner takes the offset, and the estimator's correction is what it left. The
    # correction is seen through the yaw rate: without a yaw-rate channel it stays at the
    # estimator's prior, 0 (so does this). The gate is an angle, not a radius: a scale error
    # of 25 % puts at most 5 mrad into the correction at 0.02 rad, on any wheelbase. Not
    # taken with a steering extension in the model (rack nonlinearity, understeer): the
    # estimator's eq. 7 lacks it, so its correction holds the extension's residual from the
    # last curve (bench_diagnose's rack-nonlinearity case with the extended model: 0.147 m
    # lateral RMS with the correction, 0.116 m without; the true model's 0.115).
    steer_correction_tau_s: float = 3.0
    steer_correction_gate_rad: float = 0.02
    w_steer_level: float = 0.02  # per (sw - feedforward)^2 / max^2 per s
    # terminal LQR input weights (per rad^2 of steering wheel, per (m/s^2)^2)
    r_terminal_steer: float = 0.05
    r_terminal_accel: float = 2.0
    # soft constraints: linear (exact) penalty per unit of violation per s
    w_limit_violation: float = 100.0  # accel [m/s^2], jerk [m/s^2 per stage]
    w_standstill: float = 500.0  # speed below 0 [m/s]
    w_floor: float = 10.0  # speed below the minimum-speed floor [m/s]
    w_transition: float = 10.0  # speed outside the current zone's band [m/s]; 0 = off
    w_slack_quadratic: float = 1.0
    w_speed_max: float = 100.0
    # zone-transition rule (report VI)
    transition_accel_tol_mps2: float = 0.2  # "no acceleration change": spread <= tol
    transition_window_s: float = 1.0  # checked this long either side of the crossing
    transition_dwell_s: float = 2.0  # the reference must stay in the new zone this long
    # the band kept is the zone's hysteresis band narrowed by this margin [m/s], so that
    # tracking error and the controller's 10 Hz view of the speed do not let the plant cross
    transition_band_margin_mps: float = 0.15
    # minimum-speed floor [m/s]; None: the preferred zone's lower bound; 0 disables
    min_speed_mps: float | None = None
    # stop command / obstacle: reference speed brought down at this deceleration [m/s^2]
    stop_decel_mps2: float = 1.5
    obstacle_margin_m: float = 3.0
    # controlled stop after the plan ran out: brake decel target and ramp (jerk) [m/s^2, m/s^3]
    stop_brake_decel_mps2: float = 2.0
    # OSQP
    # iteration caps: a warm-started solve (a previous plan, shifted) converges in a few tens
    # of iterations; the few that do not (a pedal-mode or zone change moves many bounds at
    # once, a stop coming) are cut here so that a step's time stays bounded
    # (tools/bench_mpc.py). A cold start (no plan: the first step, the first after a
    # standstill hold) gets the solver's own default, once. 0: by the stage count
    # (:attr:`warm_iteration_cap`), 50 up to 60 stages and 40 beyond: an iteration costs in
    # proportion to the stages (OSQP alone on a 2-core x86 host: 14 us at 50, 28 us at 100).
    # Measured on idle_hold's speed RMS, mean of 8 sensor seeds: at 50 stages 40 cut the
    # brake's convergence when stopping (0.021 -> 0.031 m/s); at 100 stages in a 50 Hz loop
    # 40 gave 0.0149 against 50's 0.0145 (ramp_sequence's unchanged), and 30 gave 0.0187
    max_iter: int = 0
    max_iter_cold: int = 4000
    # the iteration cap's use of an unfinished iterate (OSQP stopped at its cap): used
    # when its residuals (inf-norms, unscaled) are within these, else the step falls back to
    # the previous plan, shifted, and the next step continues from the iterate. OSQP's own
    # "solved" on these QPs allows eps_abs + eps_rel |z|, with positions of 100 m and more in
    # |z|: 0.1 and more; capped iterates sit at 0.1-0.25 for many steps on a hard stretch
    # (tests/controller/test_mpc_extensions.py's drag run). 0.5 (m, m/s or rad of dynamics somewhere
    # along the horizon; the command is the first stages, which the next steps refine). The
    # gradient (dual) residual OSQP accepts is eps_abs + eps_rel |q| and more, |q| of some
    # hundreds from the replan terms: 0.3 and more; capped iterates reach 1.3 (the idle
    # hold): 5
    capped_prim_tol: float = 0.5
    capped_dual_tol: float = 5.0
    eps_abs: float = 1e-3  # 1 mm, 1 mm/s: far below what the plant can act on
    # relative to the largest of |q|, |P z|, |A'y| (dual) and |A z|, |z| (primal). |q|
    # reaches 50 from the standstill penalty (``w_standstill`` dt at 0.1 s stages) when a
    # stop is in the horizon, and the brake plan seconds ahead, which no command uses, then
    # converges slowest: at 1e-3 5 % of the warm solves at 0.1 s stages on ramp_sequence
    # stopped at an iteration cap of 50 on a gradient residual of 0.06-0.08 in those
    # stages' brake, at 2e-3 0.3 %; idle_hold's speed RMS over 8 sensor seeds 0.022 and 0.019 m/s
    eps_rel: float = 2e-3
    # OSQP: test convergence every this many iterations. Warm-started (shifted primal and
    # dual) the QP converges in a few tens of iterations: a sparser test runs far past that
    check_termination: int = 5
    # OSQP's step size rho (initial value; adapted when ``adaptive_rho``): a fixed rho needs
    # far more iterations on these QPs (tools/bench_mpc.py). Adapted every this many
    # iterations (0: OSQP's timing-based choice, which adapts too late for a 15-iteration
    # solve); each adaptation refactorises the KKT matrix, as costly as the step's data
    # update, so at most ``warm_iteration_cap / adaptive_rho_interval`` of them per solve
    adaptive_rho: bool = True
    rho: float = 0.1
    adaptive_rho_interval: int = 10
    adaptive_rho_tolerance: float = 3.0
    # OSQP's Ruiz equilibration passes (its ``scaling``; its default 10). OSQP scales the data
    # again on every update of P and A, so each pass is paid every step: at 0.1 s stages the
    # update took 0.46 ms with ten (p50 in the loop; the KKT refactorisation alone 0.13 ms)
    # and 0.21 ms with two, at the same iteration counts on ramp_sequence, figure8, arcs and
    # idle_hold (tools/bench_mpc.py). One pass needed more iterations on arcs, and its 5-iteration
    # iterates were further from converged (tests/controller/test_mpc_cap.py)
    osqp_scaling: int = 2
    # OSQP relaxation (its default 1.6): from a shifted warm start strong over-relaxation
    # overshoots, and 1.2 stops in fewer iterations (tools/bench_mpc.py); 1.0 stops as early
    # but with a less converged steering plan (the MPC/NMPC agreement test,
    # tests/controller/test_nmpc.py)
    admm_alpha: float = 1.2
    time_limit_s: float = 0.0  # 0: none (OSQP time_limit)
    cold_start_iterations: int = 3  # SQP iterations when no previous plan exists
    accept_inaccurate: bool = True  # OSQP "solved inaccurate" is used (status says so)
    warm_start_shifted: bool = True  # warm-start x with the shifted plan (else OSQP's last x, y)

    def __post_init__(self):
        n = self.horizon_s / self.dt_s
        if not (
            self.dt_s > 0 and self.horizon_s > 0 and abs(n - round(n)) < 1e-6 and round(n) >= 2
        ):
            raise ValueError("MpcConfig: horizon_s must be a whole number (>= 2) of dt_s steps")
        if not self.w_speed_effort > self.w_steer_effort:
            raise ValueError(
                "MpcConfig: the report (section VI) weights velocity effort above "
                "steering effort: need w_speed_effort > w_steer_effort"
            )
        for name in (
            "w_lateral",
            "w_heading",
            "w_speed",
            "w_steer_effort",
            "w_slack_quadratic",
            "r_terminal_steer",
            "r_terminal_accel",
            "w_limit_violation",
            "w_standstill",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"MpcConfig.{name} must be positive")
        if self.w_steer_rate_change > 0 and not self.w_pedal_rate_change > self.w_steer_rate_change:
            raise ValueError(
                "MpcConfig: the report (section VI) weights velocity effort above "
                "steering effort: need w_pedal_rate_change > w_steer_rate_change"
            )
        if self.w_steer_replan > 0 and not self.w_pedal_replan > self.w_steer_replan:
            raise ValueError(
                "MpcConfig: the report (section VI) weights velocity effort above "
                "steering effort: need w_pedal_replan > w_steer_replan"
            )
        if not self.hold_brake_rate_ps > 0:
            raise ValueError("MpcConfig.hold_brake_rate_ps must be positive")
        for name in (
            "w_floor",
            "w_transition",
            "w_pedal_level",
            "w_steer_level",
            "w_steer_rate_change",
            "w_pedal_rate_change",
            "w_steer_sharpness",
            "w_steer_replan",
            "w_pedal_replan",
            "replan_window_s",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"MpcConfig.{name} must be >= 0")
        if not (self.steer_correction_tau_s >= 0 and self.steer_correction_gate_rad >= 0):
            raise ValueError(
                "MpcConfig: steer_correction_tau_s and steer_correction_gate_rad must be >= 0"
            )
        if self.osqp_scaling < 0:
            raise ValueError("MpcConfig.osqp_scaling must be >= 0")
        if self.check_termination < 1 or self.adaptive_rho_interval < 0:
            raise ValueError(
                "MpcConfig: check_termination must be >= 1 and adaptive_rho_interval >= 0"
            )
        if not self.adaptive_rho_tolerance >= 1:
            raise ValueError("MpcConfig.adaptive_rho_tolerance must be >= 1")
        if not 0 < self.admm_alpha < 2:
            raise ValueError("MpcConfig.admm_alpha must be in (0, 2)")
        if not (self.capped_prim_tol >= 0 and self.capped_dual_tol >= 0):
            raise ValueError("MpcConfig: capped_prim_tol and capped_dual_tol must be >= 0")
        if self.max_iter < 0 or self.max_iter_cold < 1:
            raise ValueError("MpcConfig: max_iter must be >= 0 and max_iter_cold >= 1")

    @property
    def n_stages(self) -> int:
        return int(round(self.horizon_s / self.dt_s))

    @property
    def warm_iteration_cap(self) -> int:
        """OSQP's iteration cap for a warm-started solve: ``max_iter``, or when 0, 50 up
        to 60 stages and 40 beyond."""
        if self.max_iter > 0:
            return self.max_iter
        return 50 if self.n_stages <= 60 else 40
