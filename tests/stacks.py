"""Other stacks' files for the tests that read them, from one variable: ``SIM2REAL_STACKS``.

``SIM2REAL_STACKS`` names a folder holding the other stacks' checkouts, each under its
repository's name (:data:`STACKS`)::

    SIM2REAL_STACKS=~/stacks make test      # ~/stacks/rl_sar, ~/stacks/unitree_mujoco, ...

A checkout is a work tree (``git clone``) or a bare clone (``git clone --bare``, or a mirror's
``repo`` folder): a file is read from the work tree when it is there, else from the repository's
``HEAD``. Tests reach the files through the ``stacks`` fixture (``tests/conftest.py``), which
marks them ``stacks`` (``pytest -m stacks`` runs them alone); unset, or with a stack missing from
the folder, such a test skips and its reason names the variable and the folder it looked for.
There is no default folder: no path of one machine is written in the repository. Every reader
of another stack's files is also tested on small files written the way that stack writes them,
which need no variable.
"""

from __future__ import annotations

import io
import os
import shutil
import subprocess
import tarfile
from pathlib import Path

import pytest

#: The variable naming the folder of the stacks' checkouts.
VARIABLE = "SIM2REAL_STACKS"
#: Each stack's folder name in it and the repository it is a checkout of (the commit the tests
#: were written against).
STACKS = {
    "rl_sar": "fan-ziqi/rl_sar (e384912)",
    "unitree_mujoco": "unitreerobotics/unitree_mujoco",
    "holosoma": "amazon-far/holosoma (fc600e7)",
    "HIMLoco": "OpenRobotLab/HIMLoco (ef289ac)",
}


class Stacks:
    """The checkouts under ``$SIM2REAL_STACKS`` (module docstring); each method skips the
    calling test, naming the variable, when the stack is not there."""

    def root(self, name: str) -> Path:
        """The checkout of stack ``name`` (a key of :data:`STACKS`)."""
        base = os.environ.get(VARIABLE, "")
        if not base:
            pytest.skip(f"{VARIABLE} unset: the folder of the other stacks' checkouts "
                        f"({name}/: {STACKS[name]})")  # fmt: skip
        path = Path(base).expanduser() / name
        if not path.is_dir():
            pytest.skip(f"{VARIABLE}={base}: no {name}/ in it ({STACKS[name]})")
        return path

    def read(self, name: str, path: str) -> bytes:
        """The bytes of ``path`` (relative to the repository's root) in stack ``name``; skips
        when the file is absent (a large file the checkout lacks)."""
        root = self.root(name)
        if (root / path).is_file():
            return (root / path).read_bytes()
        done = subprocess.run(["git", "-C", str(root), "show", f"HEAD:{path}"],
                              capture_output=True)  # fmt: skip
        if done.returncode != 0:
            pytest.skip(f"{VARIABLE}: {name}/{path} absent from the checkout")
        return done.stdout

    def copy(self, name: str, paths: list[str], dest: Path) -> Path:
        """Files or folders ``paths`` of stack ``name`` copied under ``dest`` at their own
        relative paths; returns ``dest / paths[0]``."""
        root = self.root(name)
        dest.mkdir(parents=True, exist_ok=True)
        if all((root / p).exists() for p in paths):
            for p in paths:
                if (root / p).is_dir():
                    shutil.copytree(root / p, dest / p, dirs_exist_ok=True)
                else:
                    (dest / p).parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(root / p, dest / p)
            return dest / paths[0]
        done = subprocess.run(["git", "-C", str(root), "archive", "--format=tar", "HEAD", *paths],
                              capture_output=True)  # fmt: skip
        if done.returncode != 0:
            pytest.skip(f"{VARIABLE}: {name}/{paths} absent from the checkout")
        with tarfile.open(fileobj=io.BytesIO(done.stdout)) as tar:
            tar.extractall(dest, filter="data")
        return dest / paths[0]
