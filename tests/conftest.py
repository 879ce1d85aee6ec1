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
