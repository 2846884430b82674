import os
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
if "PYTEST_XDIST_WORKER" in os.environ:  # the workers share the cores: one thread each
    for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import pytest  # noqa: E402

from robots import load_robot  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def pytest_configure(config):
    """With pytest-xdist workers (``-n N``), compile the numba kernels once in the controller
    (``tests/warm_kernels.py``) before the workers start, instead of in every worker at once."""
    if "PYTEST_XDIST_WORKER" in os.environ or not getattr(config.option, "numprocesses", 0):
        return
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
    )
    subprocess.run([sys.executable, str(REPO / "tests" / "warm_kernels.py")], cwd=REPO, env=env)


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
