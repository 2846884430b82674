import os

os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest  # noqa: E402

from robots import load_robot  # noqa: E402


# A Robot is frozen with read-only arrays: one load per session serves every test.
@pytest.fixture(scope="session")
def arm3():
    return load_robot("arm3")


@pytest.fixture(scope="session")
def arm6():
    return load_robot("arm6")


@pytest.fixture(scope="session")
def go2():
    return load_robot("go2")


@pytest.fixture(scope="session")
def so101():
    return load_robot("so101")


@pytest.fixture(scope="session")
def arm3_xm430():
    return load_robot("arm3_xm430")
