"""numba's cache of the toolkit's kernels cannot go stale (``sim2real.numba_cache``): a kernel
that calls a helper from another module of the package is compiled again after the helper's
file is edited, where numba's own key (the kernel's own file) kept running the old helper; and
an edit to a module the kernel does not import keeps its cache."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

HELPER = """import numba


@numba.njit(cache=True, inline="always")
def helper():
    return {value}
"""
KERNEL = """import numba

from sim2real._cache_probe_helper import helper


@numba.njit(cache=True)
def kernel():
    return helper()
"""
RUN = (
    "import sim2real, sim2real._cache_probe_kernel as m; "
    "print(m.kernel(), m.kernel.stats.cache_hits.get(m.kernel.signatures[0], 0))"
)


def _run(root: Path) -> tuple[int, int]:
    env = dict(os.environ, PYTHONPATH=str(root))
    env.pop("NUMBA_CACHE_DIR", None)  # the cache beside the copy's files
    done = subprocess.run(
        [sys.executable, "-c", RUN], cwd=root, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    value, hits = done.stdout.split()
    return int(value), int(hits)


def test_editing_a_helper_in_another_file_recompiles_the_kernel_that_calls_it(tmp_path):
    pkg = tmp_path / "sim2real"
    shutil.copytree(ROOT / "sim2real", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    (pkg / "_cache_probe_helper.py").write_text(HELPER.format(value=1))
    (pkg / "_cache_probe_kernel.py").write_text(KERNEL)
    assert _run(tmp_path) == (1, 0)  # compiled, written to the cache
    assert _run(tmp_path) == (1, 1)  # loaded from the cache: nothing changed
    (pkg / "_cache_probe_helper.py").write_text(HELPER.format(value=2))
    assert _run(tmp_path) == (2, 0)  # the helper's edit reached the kernel
    # another kernel's file (the guard's) and a module outside the probe's imports: no recompile
    for other in ("deploy/safety/kernel.py", "deploy/cli/deploy_run.py"):
        path = pkg / other
        path.write_text(path.read_text() + "\n# an edit\n")
    assert _run(tmp_path) == (2, 1)
