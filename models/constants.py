"""Physical constants shared by the models, each with its source."""

from __future__ import annotations

#: standard gravity [m/s^2], exact by definition (3rd CGPM, 1901)
G_MPS2 = 9.80665
