"""The Unitree backend's hand-over from the bring-up's stand to the policy: the stand's gains
(robot.toml ``[unitree] ramp_kp``/``ramp_kd``) hold through the runtime's RAMP_IN, and from the
policy's first RUNNING command the driver's PD law is the sum of the stand's (its target at the
ramp's gains) and the policy's (its target at the joints' gains), weighted over
``bringup.BLEND_TIME``. Unitree's deploy programs stand the same way (FixStand's gains until the
policy's state; unitree_rl_mjlab deploy/robots/g1/config/config.yaml). A G1 whose policy gains
cannot hold its home pose alone (the waist pitch) sagged in RAMP_IN once the gains had blended
into the policy's, and the policy's first actions sent at the stand's gains swung its waist into
its limits.

No DDS: the commands are read from the backend's LowCmd record as each is encoded; the backend's
clock is a test clock (the blend's time is the monotonic clock of
:mod:`sim2real.deploy.backends.unitree.handover`).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="pip install '.[unitree]'")

import sim2real.deploy.backends.unitree.handover as handover_module  # noqa: E402
from sim2real.deploy.backends.unitree.backend import UnitreeBackend  # noqa: E402
from sim2real.deploy.backends.unitree.bringup import BLEND_TIME  # noqa: E402
from sim2real.deploy.core.modes import Mode  # noqa: E402


class _Clock:
    """``time`` as the hand-over uses it, with a monotonic clock set by the test."""

    def __init__(self):
        self.now = 100.0

    def monotonic(self) -> float:
        return self.now


class _Wire:
    """A DDS writer that keeps each command's (q, kp, kd) in robot.toml's joint order."""

    def __init__(self, backend: UnitreeBackend):
        self.backend, self.sent = backend, []

    def write_raw(self, _data: bytes) -> None:
        mc = self.backend._cmd.message["motor_cmd"][self.backend.slots]
        self.sent.append((mc["q"].astype(float), mc["kp"].astype(float), mc["kd"].astype(float)))


@pytest.fixture
def wired(go2, monkeypatch):
    """An unopened backend for the go2 (ramp_kp 50 against its joints' 20-40) whose commands
    go to a :class:`_Wire`, with the test's clock."""
    clock = _Clock()
    monkeypatch.setattr(handover_module, "time", clock)
    lines = []
    backend = UnitreeBackend(go2, log=lines.append)
    wire = _Wire(backend)
    wire.lines = lines
    backend._writer = wire
    return backend, wire, clock


def test_the_stand_holds_through_ramp_in_and_hands_over_as_the_sum_of_both_pd_laws(go2, wired):
    backend, wire, clock = wired
    ramp_kp, ramp_kd = backend.ramp_kp, backend.ramp_kd
    kp, kd = backend.kp, backend.kd
    assert (ramp_kp != kp).all()  # the go2's stand is stiffer than its policy
    mode = np.array([Mode.IDLE], dtype=np.int8)
    backend.watch_modes(mode)
    home = np.asarray(go2.home, dtype=np.float64)
    stand = home + 0.01
    mode[0] = Mode.RAMP_IN
    backend.write(stand[None])
    clock.now += 5.0  # a long RAMP_IN: the robot still swaying; no policy acts yet
    backend.write(stand[None])
    for q, k, d in wire.sent:
        np.testing.assert_allclose(k, ramp_kp, rtol=1e-6)
        np.testing.assert_allclose(d, ramp_kd, rtol=1e-6)
        np.testing.assert_allclose(q, stand, atol=1e-6)
    assert wire.lines == []

    policy = home + np.linspace(-0.3, 0.3, go2.n_joints)
    mode[0] = Mode.RUNNING
    backend.write(policy[None])  # the policy's first command: the stand's law still, whole
    backend.write(policy[None])
    # said once, when a gantry may let go of a humanoid
    assert len(wire.lines) == 1 and "the policy runs" in wire.lines[0]
    q, k, d = wire.sent[-1]
    np.testing.assert_allclose(k, ramp_kp, rtol=1e-6)
    np.testing.assert_allclose(q, stand, atol=1e-6)

    clock.now += BLEND_TIME / 4
    backend.write(policy[None])
    q, k, d = wire.sent[-1]
    # the torque the driver applies at any angle x and speed v is the weighted sum of both laws
    for x, v in ((home, 0.0), (home - 0.2, 1.5), (home + 0.4, -2.0)):
        tau = k * (q - x) - d * v
        want = 0.75 * (ramp_kp * (stand - x) - ramp_kd * v) + 0.25 * (kp * (policy - x) - kd * v)
        np.testing.assert_allclose(tau, want, rtol=1e-5, atol=1e-4)

    clock.now += BLEND_TIME
    backend.write(policy[None])
    q, k, d = wire.sent[-1]
    np.testing.assert_allclose(k, kp, rtol=1e-6)
    np.testing.assert_allclose(d, kd, rtol=1e-6)
    np.testing.assert_allclose(q, policy, atol=1e-6)


def test_without_a_runtime_the_hand_over_starts_at_the_first_command_from_the_hold(go2, wired):
    """No mode array watched (a program of its own on the backend): the first command starts
    the hand-over, from the home pose the bring-up held."""
    backend, wire, clock = wired
    home = np.asarray(go2.home, dtype=np.float64)
    target = home + 0.2
    backend.write(target[None])
    q, k, _ = wire.sent[-1]
    np.testing.assert_allclose(k, backend.ramp_kp, rtol=1e-6)
    np.testing.assert_allclose(q, home, atol=1e-6)
    clock.now += BLEND_TIME
    backend.write(target[None])
    q, k, _ = wire.sent[-1]
    np.testing.assert_allclose(k, backend.kp, rtol=1e-6)
    np.testing.assert_allclose(q, target, atol=1e-6)


def test_the_rig_shows_the_backend_the_runtimes_modes(go2, go2_onnx, wired):
    """deploy-run's rig hands the backend the runtime's own mode array: the stand holds until
    the runtime's env is RUNNING."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.rig.rig import Rig

    backend, wire, _ = wired
    rig = Rig(go2, OnnxPolicy(go2_onnx, go2), backend, envs=1)
    rig.runtime.mode[0] = Mode.RAMP_IN
    target = np.asarray(go2.home) + 0.1
    backend.write(target[None])
    np.testing.assert_allclose(wire.sent[-1][1], backend.ramp_kp, rtol=1e-6)
    rig.runtime.mode[0] = Mode.RUNNING
    backend.write(target[None])
    backend.handover.started -= BLEND_TIME  # the blend's end
    backend.write(target[None])
    np.testing.assert_allclose(wire.sent[-1][1], backend.kp, rtol=1e-6)


def test_a_wheels_speed_target_is_never_blended_with_the_stands_pose(monkeypatch):
    """A Go2-W's wheel takes a speed target (rad/s): during the blend its column is the policy's
    speed, not a weighted mean with the stand's angle; its legs blend as every joint does."""
    from sim2real.deploy.backends.unitree.handover import StandHandover

    clock = _Clock()
    monkeypatch.setattr(handover_module, "time", clock)
    speeds = np.array([False, True])
    h = StandHandover([50.0, 50.0], [3.5, 3.5], [20.0, 0.0], [0.5, 0.5], [0.3, 0.0], speeds)
    h.command(None)  # unwatched: the policy's first command
    clock.now += BLEND_TIME / 2
    q, kp, _ = h.law(np.array([0.5, 12.0]))
    assert q[1] == 12.0
    assert q[0] == pytest.approx((25.0 * 0.3 + 10.0 * 0.5) / 35.0)
    assert kp.tolist() == pytest.approx([35.0, 25.0])
