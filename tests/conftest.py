"""Shared fixtures: paths of the real data bundled under tools/data.

The bundled files are gzip copies of ../shared/data's.
"""
from pathlib import Path

import pytest

from _data import bundled


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


def pytest_configure(config):
    """BLAS on one thread in every test process, as ``hmpc``'s CLI and drive loop run it:
    with two xdist workers on two cores, OpenBLAS's own threads oversubscribe the cores and
    a small LAPACK call (the MPC's 3x3 DARE) waits 30x longer for them."""
    from threadpoolctl import threadpool_limits
    import numpy  # noqa: F401  (load the BLAS the limit applies to)
    config._hmpc_blas_limit = threadpool_limits(limits=1, user_api="blas")
