"""``deploy-run --backend unitree`` with a wheel-legged robot: unitree_mujoco's Go2-W
(sim2real/robots/go2w, 16 motor slots of ``unitree_go``: 12 legs, then 4 wheels) against the
Unitree emulator, driven by a policy folder of rl_sar's layout (``policy/go2w/robot_lab``: legs
kp 20 on PD position targets, wheels kp 0, kd 0.5 on speed targets, tests/test_rl_sar_contract.py).

Each wheel's speed target goes in its motor command's ``dq`` with ``kp`` 0 (the driver's law
``kd (dq_des - dq)``); the bring-up and the runtime's RAMP_IN ignore a wheel's angle, which any
roll during the bring-up leaves anywhere. The emulator serves from a thread of this process,
deploy-run runs in its own, as in tests/test_unitree_backend.py.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="pip install '.[unitree]'")
pytest.importorskip("torch")

from sim2real.deploy.backends.unitree.emulator import UnitreeEmulator  # noqa: E402
from sim2real.deploy.backends.unitree.emulator.robot import TRACE_EVERY  # noqa: E402
from sim2real.robots import load_robot  # noqa: E402
from tests.test_rl_sar_contract import write  # noqa: E402

# On the wall clock against an emulator: in a process of its own beside the suite (Makefile).
pytestmark = pytest.mark.wallclock

#: The DDS domain of this test: apart from test_unitree_backend's 100-219 and the HIL test's
#: 220-231.
DOMAIN = 13
#: s of policy asked for.
POLICY_SECONDS = 4.0
#: rad/s each wheel is asked for: the policy's wheel action 1.0 x rl_sar's action scale 5.
WHEEL_SPEED = 5.0
#: m, go2w.xml's wheel radius (sim2real/robots/go2w: its collision geometry about the axle).
WHEEL_RADIUS = 0.086


def test_go2w_rolls_on_its_wheels_speed_targets_through_the_unitree_backend(tmp_path):
    """A policy holding its legs at the default pose and asking every wheel for 5 rad/s: the
    Go2-W stands up from lying, hands over to the policy and rolls forward toward the wheels'
    rim speed (0.43 m/s); a wheel sent as a position target (its speed in ``q`` with kp 0) would
    brake instead, and a wheel's angle judged against home would keep the runtime in RAMP_IN."""
    robot = load_robot("go2w")
    wheels = np.array(["_wheel_" in n for n in robot.joint_names])
    policy = write(tmp_path, bias=[0.0] * 12 + [1.0] * 4)  # rl_sar's order: legs, then wheels
    report = tmp_path / "run.json"
    argv = [
        "--backend", "unitree", "--network-interface", "lo", "--domain-id", str(DOMAIN),
        "--robot", "go2w", "--policy", str(policy), "--duration", str(POLICY_SECONDS),
        "--command", "0,0,0", "--heading-hold", "0", "--report", str(report),
        # the link and the wheels are judged, not deadline keeping: the emulator's plant
        # shares this machine with deploy-run
        "--overrun-limit", "0.5",
    ]  # fmt: skip
    with UnitreeEmulator(robot, domain_id=DOMAIN) as emu:
        done = subprocess.run(
            [sys.executable, "-m", "sim2real.deploy.cli.deploy_run", *argv],
            capture_output=True,
            text=True,
            timeout=240,
        )
        trace = np.array(emu.trace)
        commands = list(emu.commands)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    r = json.loads(report.read_text())
    assert r["final_state"] == ["RUNNING"], out
    assert r["faults"]["safe_stops"] == 0 and r["locomotion"]["falls"] == 0, out
    # the runtime's commands (the legs' kp under the bring-up's ramp_kp, blending into the
    # policy's 20): legs on PD targets, wheels on speed (kp 0, kd > 0)
    ramp_kp = robot.config.unitree.ramp_kp
    policy = [(t, k, kd) for t, _, k, kd in commands if (0 < k[~wheels]).all()]
    policy = [(t, k, kd) for t, k, kd in policy if (k[~wheels] < ramp_kp - 1e-3).all()]
    assert policy, out
    assert all((k[wheels] == 0).all() and (kd[wheels] > 0).all() for _, k, kd in policy)
    # the emulator's plant rolled forward while the policy ran
    start, end = policy[0][0], policy[-1][0]
    rolling = trace[(trace[:, 0] >= start) & (trace[:, 0] <= end)]
    forward = rolling[-1, 1] - rolling[0, 1]
    # judged on the plant's own time: on a busy machine it simulates less than the clock
    rolled_s = len(rolling) * TRACE_EVERY * robot.physics_timestep
    assert rolled_s > 0.5 * POLICY_SECONDS, (rolled_s, out)
    # from rest, through kd 0.5 N m s/rad alone (the wheel's torque up to 2.5 N m), and each
    # wheel braked instead of driven on main's LowCmd: 0 m
    rim = WHEEL_SPEED * WHEEL_RADIUS
    assert forward > 0.2 * rim * rolled_s, (forward, rolled_s, out)
