"""Hidden parameter sets: a simulated car a seeded draw away from the parameter file its
controller is given (the online model estimator's acceptance, tests/test_adapt*.py, and its
figures, tools/adaptation_figures.py).

``hidden_params(base, seed)``: the steering scale and every zone's accelerator and brake gains
each scaled by ``1 +- U(0.10, 0.25)`` (sign drawn too), the steering offset moved by +-13 mrad;
zone offsets and boundaries, geometry and everything else as in ``base``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hmpc.models.params import Params, dump_params

#: the factor range of a hidden gain (either sign): 10-25 %, a loaded car, other tyres, pads
GAIN_CHANGE = (0.10, 0.25)
#: the offset's shift [rad]: 0.75 deg of road-wheel angle, an alignment after a kerb strike
OFFSET_SHIFT_RAD = 0.013


def _factor(rng: np.random.Generator) -> float:
    return 1.0 + float(rng.choice((-1.0, 1.0))) * float(rng.uniform(*GAIN_CHANGE))


def hidden_params(base: Params, seed: int) -> Params:
    """``base`` with its gains and steering offset moved by a seeded draw (module doc)."""
    rng = np.random.default_rng(int(seed))
    st = base.steering
    assert st is not None  # base is a complete model
    steering = replace(
        st,
        scale=st.scale * _factor(rng),
        offset_rad=st.offset_rad + float(rng.choice((-1.0, 1.0))) * OFFSET_SHIFT_RAD,
    )
    zones = [
        replace(
            z,
            scale_mps2=z.scale_mps2 * _factor(rng),
            brake_scale_mps2=z.brake_scale_mps2 * _factor(rng),
        )
        for z in base.zones
    ]
    return replace(base, steering=steering, zones=zones, path=f"hidden-{seed}")


def write_hidden(base: Params, seed: int, path) -> str:
    """:func:`hidden_params` written as a parameter file at ``path``."""
    dump_params(hidden_params(base, seed), path)
    return str(path)
