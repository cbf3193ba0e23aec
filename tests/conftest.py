import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("VOLRENDER_SHARED_DATA", ROOT.parent / "shared" / "data"))


def pytest_configure(config):
    """One device for the whole suite. The tests that render through the CLI, the API or
    a subprocess pass no device, so they get $VOLRENDER_DEVICE's (else PoCL): point it at
    $VOLRENDER_TEST_DEVICE, the device of the cl_device fixture, or remove it when that
    is unset, so that a GPU run of the suite is a GPU run throughout."""
    spec = os.environ.get("VOLRENDER_TEST_DEVICE")
    if spec:
        os.environ["VOLRENDER_DEVICE"] = spec
    else:
        os.environ.pop("VOLRENDER_DEVICE", None)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def shared_data():
    """Real third-party files that live beside the checkout, never in it."""
    if not SHARED.is_dir():
        pytest.skip(f"real data not found at {SHARED} (a user's clone has no ../shared; "
                    "set VOLRENDER_SHARED_DATA to use it)")
    return SHARED


@pytest.fixture(scope="session")
def cl_device():
    """The OpenCL device under test: PoCL, or $VOLRENDER_TEST_DEVICE (a device spec)."""
    from volrender import device
    return device.get(os.environ.get("VOLRENDER_TEST_DEVICE"))
