import functools
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


_NO_OPENVDB = "OpenVDB's Python binding is not available"


@functools.lru_cache(maxsize=None)
def openvdb_missing() -> str | None:
    """Why OpenVDB's Python binding cannot be imported here, or None when it can."""
    from volrender.errors import UserError
    from volrender.vdb import import_openvdb
    try:
        import_openvdb()
    except UserError as exc:
        return "OpenVDB's Python binding (pyopenvdb or openvdb) cannot be imported here"
    return None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """A test that fails because OpenVDB's binding is missing (it reads or writes a .vdb:
    volrender says so in its error, which the failure or the captured output shows) is
    reported as skipped, with the reason, where the binding cannot be imported; where it
    can, nothing changes."""
    outcome = yield
    rep = outcome.get_result()
    if not rep.failed or call.excinfo is None:
        return
    text = rep.longreprtext + "".join(content for _, content in rep.sections)
    for entry in call.excinfo.traceback:       # an error read back: capsys, a subprocess
        for value in entry.frame.f_locals.values():
            value = getattr(value, "stderr", value)
            if isinstance(value, (str, bytes, tuple)):
                text += str(value)[:100_000]
    if _NO_OPENVDB in text or "No module named 'pyopenvdb'" in text:
        reason = openvdb_missing()
        if reason:
            rep.outcome = "skipped"
            rep.longrepr = (str(item.path), (item.location[1] or 0) + 1,
                            f"Skipped: needs a .vdb file read or written, and {reason}")


@pytest.fixture(scope="module")
def client():
    """A 2-worker Dask cluster of processes (one PoCL thread each), per test module."""
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=40,
                                       env={"POCL_MAX_PTHREAD_COUNT": "1"})
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture
def log(monkeypatch):
    """The kernel launches' arguments and faked times (helpers.fake_cost)."""
    from helpers import spy_args
    d = {"launches": [], "clock": 0.0, "args": ()}
    spy_args(monkeypatch, d)
    return d


@pytest.fixture(scope="module")
def box():
    """A 12^3 grid holding a 6^3 cube of density 1 (test_python_api, test_everyday)."""
    g = np.zeros((12, 12, 12), np.float32)
    g[3:9, 3:9, 3:9] = 1.0
    return g
