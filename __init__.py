"""hmpc: honest steering and accelerator models of a car from its own CAN/GNSS data, and a
hybrid-mode MPC that drives it (UC Berkeley report EECS-2008-92).

The one import package. Its sub-packages are the repository's top-level folders, mapped by
``pyproject.toml``: ``hmpc.models`` (offline math), ``hmpc.controller`` (runtime) and
``hmpc.tools`` (the ``hmpc`` console script). Imports flow tools -> controller -> models.
"""

__version__ = "0.1.0"
