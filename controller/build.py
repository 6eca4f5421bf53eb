"""A controller from a parameter file: what ``simulate``, ``drive``, ``teleop`` and ``replay`` run.

:func:`load_model` reads a complete model and checks its ``identifiable: false`` flags;
:func:`make_controller` builds the named controller (``mpc``: the hybrid MPC on OSQP,
``nmpc``: CasADi/IPOPT, ``pid``: the baseline) for it.
"""

from __future__ import annotations

from hmpc.models.params import Params, load_params
from hmpc.models.unidentifiable import check_identifiable

from hmpc.controller.base import Controller

#: the controllers :func:`make_controller` builds
CONTROLLERS = ("mpc", "nmpc", "pid")


def load_model(path, *, accept_unidentifiable: bool = False) -> tuple[Params, list[str]]:
    """A complete model from ``path`` for a controller or plant, and its warning lines.

    Refuses (ParamError naming the key) a file lacking a part and, unless
    ``accept_unidentifiable``, values flagged ``identifiable: false``; with the flag each such
    value gives one warning line.
    """
    params = load_params(path, require_model=True)
    return params, check_identifiable(params, accept=accept_unidentifiable)


def make_controller(
    name: str,
    params: Params,
    *,
    dt_s: float = 0.2,
    horizon_s: float = 10.0,
    transition_penalty: bool = True,
    accept_unidentifiable: bool = False,
) -> Controller:
    """The controller ``name`` (one of :data:`CONTROLLERS`) for ``params``.

    Args:
        name: the controller's name (a key of :data:`CONTROLLERS`).
        params: the model the controller is built for.
        dt_s: MPC stage length [s].
        horizon_s: MPC horizon [s].
        transition_penalty: keep the MPC's zone-transition penalty (off: its weight is 0).
        accept_unidentifiable: use values flagged ``identifiable: false`` (refused otherwise,
            ParamError naming key and flag).

    Raises:
        ValueError: an unknown controller name.
    """
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller {name!r} (known: {', '.join(CONTROLLERS)})")
    check_identifiable(params, accept=accept_unidentifiable)
    # each controller's module (OSQP and scipy.sparse, CasADi) loads only when that controller
    # is built: commands that never build one (ingest, identify) start without them
    from hmpc.controller.mpc import MpcConfig, MpcController

    if name == "pid":
        from hmpc.controller.pid import PidController

        return PidController(params)
    kw: dict = {"dt_s": dt_s, "horizon_s": horizon_s}
    if not transition_penalty:
        kw["w_transition"] = 0.0
    cfg = MpcConfig(**kw)
    if name == "nmpc":
        from hmpc.controller.nmpc import NmpcController  # CasADi loads only when asked for

        return NmpcController(params, cfg)
    return MpcController(params, cfg)
