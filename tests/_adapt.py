"""Hidden parameter sets for the online model estimator's tests (tests/adapt/): a
simulated car a seeded draw away from the file the controller is given
(``hmpc.models.sim.hidden``, also behind tools/adaptation_figures.py)."""

from __future__ import annotations

from hmpc.models.sim.hidden import GAIN_CHANGE, OFFSET_SHIFT_RAD, hidden_params, write_hidden

__all__ = ["GAIN_CHANGE", "OFFSET_SHIFT_RAD", "hidden_params", "write_hidden"]
