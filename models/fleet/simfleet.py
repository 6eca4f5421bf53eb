"""Simulated fleets for tests and ``tools/bench_fleet.py``: drives of known cars from the
ground-truth simulator (``models.sim``), written as canonical recordings with a manifest.

A drive is the report's experiments run one after another (``DRIVE_EXPERIMENTS``, each with
its own seed) until it lasts ``duration_s``; a vehicle is a truth parameter set
(``models.sim.simulator.random_params``) that may change from one drive on (a concealed
drift: ``pedal_factor`` scales every zone's accelerator and brake gains).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

import yaml

from hmpc.models.identify.pipeline import concat_recordings
from hmpc.models.params import Params
from hmpc.models.sim.simulator import random_params, simulate_experiment

#: the order in which a drive runs the experiments: steering and longitudinal evidence first,
#: so that a short drive (two or three experiments) still identifies every part
DRIVE_EXPERIMENTS = ("arcs", "open_loop", "ramps", "circles", "ramp_sequence", "figure8")

#: first drive's start; drives of one vehicle a day apart (any fixed date: repeatable files)
_START = datetime(2026, 1, 5, 8, 0, tzinfo=timezone.utc)


@dataclass(frozen=True)
class SimVehicle:
    """A simulated car: ``truth_seed`` draws its parameters; from drive number
    ``drift_from`` (1-based) on, every zone's accelerator and brake gain is multiplied by
    ``pedal_factor`` (None: no drift)."""

    vehicle_id: str
    truth_seed: int
    drift_from: int | None = None
    pedal_factor: float = 1.0

    def truth(self, drive_no: int) -> Params:
        p = random_params(self.truth_seed)
        if self.drift_from is not None and drive_no >= self.drift_from:
            p = replace(
                p,
                zones=[
                    replace(
                        z,
                        scale_mps2=z.scale_mps2 * self.pedal_factor,
                        brake_scale_mps2=z.brake_scale_mps2 * self.pedal_factor,
                    )
                    for z in p.zones
                ],
            )
        return p


def simulate_drive(truth: Params, seed: int, duration_s: float = 600.0):
    """One drive: ``DRIVE_EXPERIMENTS`` in turn (seeds ``seed*100 + i``) until the
    recording lasts at least ``duration_s``; a canonical Recording."""
    recs, total_s, i = [], 0.0, 0
    while total_s < duration_s:
        name = DRIVE_EXPERIMENTS[i % len(DRIVE_EXPERIMENTS)]
        rec = simulate_experiment(name, truth, seed=seed * 100 + i)
        recs.append(rec)
        total_s += float(rec.meta["duration_s"])
        i += 1
    return concat_recordings(recs)


def write_fleet(
    folder,
    vehicles: list[SimVehicle],
    drives_per_vehicle: int,
    *,
    duration_s: float = 600.0,
    seed: int = 0,
    fmt: str = "parquet",
) -> Path:
    """Simulate every drive of ``vehicles`` into ``folder`` (recordings, one geometry file
    per vehicle, ``manifest.csv``); return the manifest's path. Drive ids are
    ``<vehicle_id><n>`` (``A1``, ``A2``, ...), n from 1; vehicle i's drive n starts on day n,
    i hours after the first."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for vi, v in enumerate(vehicles):
        geo = folder / f"{v.vehicle_id}.geometry.yaml"
        veh = random_params(v.truth_seed).vehicle
        geo.write_text(
            yaml.safe_dump(
                {"vehicle": {"wheelbase_m": veh.wheelbase_m, "track_front_m": veh.track_front_m}}
            )
        )
        for n in range(1, drives_per_vehicle + 1):
            drive_id = f"{v.vehicle_id}{n}"
            rec = simulate_drive(
                v.truth(n), seed=seed * 10_000 + vi * 1000 + n, duration_s=duration_s
            )
            path = folder / f"{drive_id}.{fmt}"
            rec.save(path)
            start = _START + timedelta(days=n - 1, hours=vi)
            rows.append(
                {
                    "vehicle_id": v.vehicle_id,
                    "drive_id": drive_id,
                    "start_time": start.strftime("%Y-%m-%dT%H:%M:%SZ"),
                    "geometry": geo.name,
                    "recording": path.name,
                }
            )
    manifest = folder / "manifest.csv"
    with open(manifest, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(
            fh, fieldnames=["vehicle_id", "drive_id", "start_time", "geometry", "recording"]
        )
        w.writeheader()
        w.writerows(rows)
    return manifest
