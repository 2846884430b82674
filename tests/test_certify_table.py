"""The motion envelope's certify over its packed table
(:mod:`sim2real.deploy.safety.certify_table`) decides as the same kernel called
with its thirty arrays: two runtimes run the scripted ticks of ``tests/test_compiled_tick.py``
(an adversarial policy, faults, pushes; two envs), one whose envelope never builds the table.
Commands, the guard's counters, the envelope's unsafe envs and braked joints, the drives'
integrators: bit for bit. Also: the table is built for the runtime's arrays (velocity mode: the
mass matrix in Pinocchio's Fortran order for one env), and not for an array of another dtype."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.runtime import Runtime
from sim2real.deploy.safety import certify_table
from tests.runtime_fixtures import adversarial_onnx
from tests.test_compiled_tick import build

TICKS = 1200


def run(rt: Runtime) -> dict[str, np.ndarray]:
    env = rt.guard.envelope
    out: dict[str, list] = {"command": [], "counts": [], "unsafe": [], "joints": [], "mode": []}
    if env.drive is not None:
        out["setpoint"] = []
    for _ in range(TICKS):
        rt.tick()
        out["command"].append(rt.command.copy())
        out["counts"].append(rt.guard.count_matrix.copy())
        out["unsafe"].append(env.unsafe.copy())
        out["joints"].append(env.joints.copy())
        out["mode"].append(rt.mode.copy())
        if env.drive is not None:
            out["setpoint"].append(env.drive.setpoint.copy())
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("robot_name", ["arm3", "arm6"])
@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_the_table_call_equals_the_arrays_call(tmp_path, request, monkeypatch, robot_name, mode):
    robot = request.getfixturevalue(robot_name)
    path = adversarial_onnx(tmp_path, robot, mode, nan_probability=0.02)
    tabled = build(robot, mode, path, Runtime)
    a = run(tabled)
    assert len(tabled.guard.envelope._certify.args) == 1  # bound to the table alone
    monkeypatch.setattr(certify_table, "build", lambda *args: None)
    plain = build(robot, mode, path, Runtime)
    b = run(plain)
    assert len(plain.guard.envelope._certify.args) == 9  # bound to the arrays
    assert a["counts"][-1].sum() > 0  # the guard intervened: the envelope's paths ran
    for key in a:
        assert a[key].tobytes() == b[key].tobytes(), key


def test_no_table_for_an_array_of_another_dtype(arm3):
    from sim2real.deploy.safety.guard import SafetyGuard

    guard = SafetyGuard(arm3, 1, "velocity")
    guard.trust_estimate(np.zeros((2, 2, 1, arm3.n_joints)).transpose(2, 3, 0, 1))
    env = guard.envelope
    z = np.zeros((1, arm3.n_joints))
    z3 = np.zeros((3, 1, arm3.n_joints))
    args = (z, z.copy(), z3, z3.copy(), np.zeros(1, dtype=bool), np.ones_like(z), z.copy())
    drive = env._drive_arrays(z)
    table = certify_table.build(args, env._screen, drive)
    assert table is not None and table.arrays["mass_fortran"]  # Pinocchio's order
    bad = (*args[:4], np.zeros(1, dtype=np.int64), *args[5:])
    assert certify_table.build(bad, env._screen, drive) is None
    strided = drive._replace(variance=np.zeros((1, arm3.n_joints, 2))[..., 1])
    assert certify_table.build(args, env._screen, strided) is None
