"""The public API package: ``sim2real`` exposes the toolkit's entry points and cannot be shadowed
by a user's own ``robots/`` folder (the layout the README suggests for robot descriptions)."""

from __future__ import annotations

import subprocess
import sys

import sim2real


def test_every_public_name_resolves():
    for name in sim2real.__all__:
        assert getattr(sim2real, name) is not None, name
    assert sorted(dir(sim2real)) == sorted(sim2real.__all__)


def test_a_users_robots_folder_does_not_shadow_the_toolkit(tmp_path):
    (tmp_path / "robots" / "my_arm").mkdir(parents=True)
    code = (
        "import sys\n"
        "from sim2real import load_robot, PolicySpec\n"
        "arm = load_robot('arm3')\n"
        "assert PolicySpec.for_robot(arm).act_dim == 3\n"
        "assert 'mujoco' in sys.modules\n"
        "print('ok')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"
    # the bare top-level name is shadowed there: the reason the public package exists
    bare = subprocess.run(
        [sys.executable, "-c", "from robots import load_robot"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert bare.returncode != 0 and "load_robot" in bare.stderr


def test_importing_the_package_loads_no_simulator(tmp_path):
    code = "import sys, sim2real; print('mujoco' in sys.modules, 'onnxruntime' in sys.modules)"
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert done.stdout.strip() == "False False", done.stderr
