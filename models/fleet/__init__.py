"""Many drives at once: ``hmpc fleet run`` (manifest -> store, on a Dask cluster: ``engine``,
``drive``, ``store``, ``manifest``) and ``hmpc fleet report`` (per vehicle and parameter the
drives, pooled value and drift: ``report``, ``stats``, ``html``); ``simfleet`` writes
simulated fleets of known cars for tests and benchmarks.
Imports hmpc.models (logs, identify, diagnose, params, sim for simfleet, report for the
figures); never controller or tools.
"""
