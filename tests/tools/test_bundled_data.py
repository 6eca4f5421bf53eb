"""The gzip copies under tools/data are byte-identical to ../shared/data (when it is beside us)."""

import gzip

import pytest

from _data import DATA_DIR, REPO_DIR

SHARED = REPO_DIR.parent / "shared" / "data"
BUNDLED = sorted(p.relative_to(DATA_DIR) for p in DATA_DIR.rglob("*.gz"))


def test_bundle_is_complete_and_small():
    names = {str(p) for p in BUNDLED}
    for need in (
        "dbc/toyota_rav4_2017.dbc.gz",
        "dbc/toyota_rav4_2019_tss2.dbc.gz",
        "rav4-comma2k19/can.log.gz",
        "rav4-comma2k19/nav.csv.gz",
        "rav4-comma2k19/imu.csv.gz",
        "rav4-comma2k19/reference_decoded.csv.gz",
        "rav4-comma2k19/reference_steering.csv.gz",
        "rav4-2019-verifiedcan/drive.csv.gz",
        "catvehicle-bagpy/catvehicle-vel.csv.gz",
        "catvehicle-bagpy/gps_odom.csv.gz",
        "f1tenth-frictionmaps/DS5_commandData.csv.gz",
        "f1tenth-frictionmaps/DS5_odomData.csv.gz",
        "f1tenth-frictionmaps/DS5_imuData.csv.gz",
        "f1tenth-frictionmaps/DS5_pfPoseData.csv.gz",
    ):
        assert need in names
    for lic in (
        "dbc/LICENSE.opendbc",
        "rav4-comma2k19/LICENSE.comma2k19",
        "rav4-2019-verifiedcan/LICENSE.VerifiedCAN",
        "catvehicle-bagpy/LICENSE",
        "f1tenth-frictionmaps/LICENSE",
    ):
        assert (DATA_DIR / lic).is_file()
    total = sum(p.stat().st_size for p in DATA_DIR.rglob("*") if p.is_file())
    assert total <= 3 * 1024 * 1024


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data is not beside this clone")
@pytest.mark.parametrize("rel", BUNDLED, ids=str)
def test_bundled_copy_equals_shared(rel):
    """A shared file that is itself gzip (the topic CSV exports) is copied as it is; the
    others are gzip copies of the shared file."""
    if (SHARED / rel).is_file():
        assert (DATA_DIR / rel).read_bytes() == (SHARED / rel).read_bytes()
        return
    original = SHARED / str(rel)[: -len(".gz")]
    assert gzip.decompress((DATA_DIR / rel).read_bytes()) == original.read_bytes()


def test_the_packages_own_lookup_finds_the_same_files():
    """hmpc.tools.datafiles (used by the demo and the benchmarks) points at the same folders."""
    from hmpc.tools import datafiles

    assert datafiles.DATA_DIR.resolve() == DATA_DIR.resolve()
    assert datafiles.PARAMS_DIR.resolve() == (REPO_DIR / "params").resolve()
    for rel in BUNDLED:
        assert datafiles.bundled(str(rel)).is_file()
