"""Test configuration: import piezopress first so that its thread settings apply before numpy loads.

Tests against a real NI-DAQmx board run only when asked for: ``pytest --daq Dev1`` runs the
tests marked ``daq`` on device ``Dev1``; without the option they are skipped.
"""

import pytest

import piezopress  # noqa: F401  (sets OPENBLAS_NUM_THREADS before numpy is imported)


def pytest_addoption(parser):
    parser.addoption(
        "--daq",
        action="store",
        default=None,
        metavar="DEVICE",
        help="run the tests marked 'daq' against this NI-DAQmx device (e.g. Dev1); they drive its analog output",
    )


def pytest_configure(config):
    config.addinivalue_line("markers", "daq: needs a real NI-DAQmx board (run with --daq DEVICE)")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--daq"):
        return
    skip = pytest.mark.skip(reason="needs a real NI-DAQmx board: run with --daq DEVICE")
    for item in items:
        if "daq" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def daq_device(request):
    """The device given with ``--daq`` (tests using it are marked ``daq``)."""
    return request.config.getoption("--daq")


# CI must be reproducible: the same examples on every run (locally, Hypothesis explores).
import os  # noqa: E402

from hypothesis import settings as _hyp_settings  # noqa: E402

_hyp_settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    _hyp_settings.load_profile("ci")


# The shared real data sets: PIEZOPRESS_DATASETS, else ../shared/datasets beside the checkout.
# Outside CI a test that needs them is skipped (saying where they were looked for); under
# CI=true their absence is a failure of every such test, never a silent skip.
from pathlib import Path  # noqa: E402

DATASETS = Path(
    os.environ.get("PIEZOPRESS_DATASETS", Path(__file__).resolve().parents[1].parent / "shared" / "datasets")
)


def needs_datasets(*relative: str):
    """Mark a test that reads the shared data sets (the files ``relative`` to DATASETS)."""
    have = all((DATASETS / r).exists() for r in relative or ("smarthysteresis", "aye-ang-2018"))
    if os.environ.get("CI") and not have:
        return pytest.mark.usefixtures("_datasets_missing_in_ci")
    return pytest.mark.skipif(
        not have, reason=f"shared data sets not found in {DATASETS} (set PIEZOPRESS_DATASETS to where they are)"
    )


@pytest.fixture
def _datasets_missing_in_ci():
    pytest.fail(f"CI: the shared data sets are not in {DATASETS} (PIEZOPRESS_DATASETS); real-data tests must run in CI")


#: How each shared data set is imported (README, "The shared data sets"): the source, then the options.
IMPORTS = {
    "smart": (
        "smarthysteresis/hysteresis_v_150_1hz.csv",
        "--no-header --kind sine --col t_s=2 --col displacement_um=3 --col command_v=4 --sample-rate-hz 5000",
    ),
    "aye": (
        "aye-ang-2018/Model_Vi_Do.dat",
        "--no-header --delimiter tab --kind sine --col command_v=1 --col displacement_um=5 --lag displacement_um=1 "
        "--sample-rate-hz 200",
    ),
}


def import_args(which: str, out) -> list[str]:
    """``piezopress import`` arguments for a shared data set into ``out``."""
    source, options = IMPORTS[which]
    return ["import", str(DATASETS / source), "--out", str(out), *options.split()]


@pytest.fixture(scope="session")
def sample_base_bundle(tmp_path_factory):
    """``fit --base`` on ``sample_runs/characterization``, written once per session (the base
    model the diagnosis tests extend)."""
    from pathlib import Path

    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import fit as F

    char = Path(__file__).resolve().parents[1] / "sample_runs" / "characterization"
    out = tmp_path_factory.mktemp("sample-base") / "base.json"
    B.write_document(F.fit_bundle([char], base=True).doc, out)
    return out
