"""Shared fixtures: paths of the real data bundled under tools/data (gzip copies of
../shared/data), and the bundled recordings ingested once per test process."""

from pathlib import Path

import numpy as np
import pytest

from _data import PARAMS_DIR, bundled


@pytest.fixture(scope="session")
def comma_log() -> Path:
    """One real minute of a 2017 RAV4, candump -L (comma2k19), gzip."""
    return bundled("rav4-comma2k19/can.log.gz")


@pytest.fixture(scope="session")
def comma_dbc() -> Path:
    """The 2017 RAV4 powertrain DBC (opendbc), gzip."""
    return bundled("dbc/toyota_rav4_2017.dbc.gz")


@pytest.fixture(scope="session")
def vcan_log() -> Path:
    """115 s of a 2019 RAV4 (VerifiedCAN), libpanda CSV, gzip."""
    return bundled("rav4-2019-verifiedcan/drive.csv.gz")


@pytest.fixture(scope="session")
def vcan_dbc() -> Path:
    """The 2019 RAV4 TSS2 DBC (opendbc), gzip."""
    return bundled("dbc/toyota_rav4_2019_tss2.dbc.gz")


def _shared(res):
    """Hand one ingest result to every test that asks for it: its arrays are made read-only
    (a test writing into them fails where it writes), and a test that adds or drops a channel
    fails at the end of the session, naming the channels."""
    rec = res.recording
    for arr in [*rec.channels.values(), *(a for pair in rec.raw.values() for a in pair)]:
        if isinstance(arr, np.ndarray):
            arr.flags.writeable = False
    names = (sorted(rec.channels), sorted(rec.raw))
    yield res
    assert (sorted(rec.channels), sorted(rec.raw)) == names, (
        "a test changed the shared ingest's channels; copy the recording before changing it"
    )


@pytest.fixture(scope="session")
def comma_ingest(comma_log, comma_dbc):
    """The comma minute as ``ingest_files`` reads it with every option at its default: the CAN
    log through params/toyota_rav4_2017.signals.yaml, with the bundled INS and IMU files."""
    from hmpc.models.logs.ingest import ingest_files

    yield from _shared(
        ingest_files(
            comma_log,
            comma_dbc,
            PARAMS_DIR / "toyota_rav4_2017.signals.yaml",
            nav_path=bundled("rav4-comma2k19/nav.csv.gz"),
            imu_path=bundled("rav4-comma2k19/imu.csv.gz"),
        )
    )


@pytest.fixture(scope="session")
def comma_can_ingest(comma_log, comma_dbc):
    """The comma minute from its CAN log alone (no INS, no IMU), options at their defaults."""
    from hmpc.models.logs.ingest import ingest_files

    yield from _shared(
        ingest_files(comma_log, comma_dbc, PARAMS_DIR / "toyota_rav4_2017.signals.yaml")
    )


@pytest.fixture(scope="session")
def vcan_ingest(vcan_log, vcan_dbc):
    """The VerifiedCAN drive through params/toyota_rav4_2019.signals.yaml, options at their
    defaults (the drive has CAN only)."""
    from hmpc.models.logs.ingest import ingest_files

    yield from _shared(
        ingest_files(vcan_log, vcan_dbc, PARAMS_DIR / "toyota_rav4_2019.signals.yaml")
    )


@pytest.hookimpl(hookwrapper=True)
def pytest_collection_modifyitems(session, config, items):
    """Before ``-m`` deselects: every real-time test sits in a file that says
    ``mark.realtime``, the files ``make test`` runs in its real-time phase (a test marked
    another way would run in neither phase).

    After: the tests marked ``long`` first, each followed by one other test, the rest in their
    order. xdist's ``load`` schedule hands each worker two consecutive tests to start with, so
    every long test starts at once on a worker of its own; a parallel run then ends no later
    than its longest test plus start-up. The order is a pure function of the collection, the
    same in every xdist worker, as xdist requires."""
    said: dict = {}
    for it in items:
        if it.get_closest_marker("realtime") is not None:
            if it.path not in said:
                said[it.path] = "mark.realtime" in it.path.read_text()
            if not said[it.path]:
                raise pytest.UsageError(
                    f"{it.nodeid}: marked realtime, but its file does not say 'mark.realtime' "
                    "(make test runs the real-time tests of the files that do)"
                )
    yield
    long = [it for it in items if it.get_closest_marker("long") is not None]
    rest = [it for it in items if it.get_closest_marker("long") is None]
    order = []
    for it in long:
        order.append(it)
        if rest:
            order.append(rest.pop(0))
    items[:] = order + rest


def pytest_configure(config):
    """BLAS on one thread in every test process, as ``hmpc``'s CLI and drive loop run it:
    with two xdist workers on two cores, OpenBLAS's own threads oversubscribe the cores and
    a small LAPACK call (the MPC's 3x3 DARE) waits 30x longer for them."""
    from threadpoolctl import threadpool_limits
    import numpy  # noqa: F401  (load the BLAS the limit applies to)

    config._hmpc_blas_limit = threadpool_limits(limits=1, user_api="blas")
