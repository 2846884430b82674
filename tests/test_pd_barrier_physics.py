"""The PD barrier's decision against the exact motion of a PD joint (sim2real/deploy/safety/
pd_barrier.py): a joint of inertia ``I`` under ``tau = kp (target - q) - kd dq + d`` (``d`` the
gravity torque toward the limit the barrier assumes) is a damped oscillator about ``target + d /
kp``, solved in closed form. Whatever the barrier's own integration, a target whose exact motion
over the control period stops short of the hard limit less the margin (and ends slow enough to
brake before it) passes unchanged, and one whose exact motion passes it is changed, to a target
whose exact motion does not."""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.safety import pd_barrier as pb
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.robots import load_robot

#: rad, and a share of the braking speed: how clearly a case must lie on one side of the bound
#: to be judged. The barrier steps the plant's semi-implicit Euler at the physics step (2 ms),
#: not the exact solution: at the hip yaw's sqrt(kp / I) = 57 rad/s (0.11 rad a step) its path
#: is up to 6 mrad short of the exact one braking from 6 rad/s and 15 mrad long of it starting
#: from rest under a 51 N m step (the first step's velocity taken whole).
DECISIVE, SPEED_SHARE = 0.02, 0.8


def exact(q0, v0, target, inertia, kp, kd, d, period, samples=2001):
    """(q, v) over ``period`` (s) of ``I q'' = kp (target - q) - kd q' + d`` from ``q0``, ``v0``
    (an underdamped oscillator about ``target + d / kp``), and the torque's largest size (N m)."""
    w0 = math.sqrt(kp / inertia)
    zeta = kd / (2.0 * math.sqrt(kp * inertia))
    assert zeta < 1.0
    wd = w0 * math.sqrt(1.0 - zeta * zeta)
    x0 = q0 - (target + d / kp)
    a, b = x0, (v0 + zeta * w0 * x0) / wd
    t = np.linspace(0.0, period, samples)
    decay = np.exp(-zeta * w0 * t)
    x = decay * (a * np.cos(wd * t) + b * np.sin(wd * t))
    v = decay * (
        (b * wd - zeta * w0 * a) * np.cos(wd * t) - (a * wd + zeta * w0 * b) * np.sin(wd * t)
    )
    q = x + target + d / kp
    tau = kp * (target - q) - kd * v
    return q, v, float(np.abs(tau).max())


def test_the_barrier_passes_a_target_whose_exact_motion_stops_short_and_changes_one_that_does_not():
    """H1-2's left hip yaw (kp 200 N m/rad, kd 2.5 N m s/rad, its least inertia, its foot in the
    air), 0.03-0.2 rad short of its upper bound and moving at -2 to 6 rad/s, or the mirror toward
    its lower one; targets from 0.3 rad behind it to 0.5 rad past the hard limit, the torque
    inside the drive's effort and torque-speed line. The barrier agrees with the exact motion on
    every case clear of the bound by DECISIVE: a safe target passes; an unsafe one is changed,
    and the changed one's exact motion stays off the bound. (The compiled guard; its numpy
    reference equals it: tests/test_pd_barrier.py.)"""
    robot = load_robot("h1_2")
    j = robot.joint_names.index("left_hip_yaw_joint")
    guard = SafetyGuard(robot, 1, "position")
    c = pb.pd_barrier_constants(guard)
    kp, kd = c[pb.KP, j], c[pb.KD, j]
    inertia = 1.0 / c[pb.INV_INERTIA, j]
    effort = robot.effort_limit[j]
    stall, no_load = c[pb.STALL, j], c[pb.NO_LOAD, j]
    period = robot.control_period
    passed = changed = 0
    for side in (1.0, -1.0):  # the upper limit, then the lower one mirrored
        bound = c[pb.BOUND_UP, j] if side > 0 else c[pb.BOUND_DOWN, j]  # mirrored: -(lower + m)
        limit = robot.position_upper[j] if side > 0 else -robot.position_lower[j]
        for gap in (0.03, 0.08, 0.2):
            for speed in (-2.0, 0.0, 2.0, 4.0, 6.0):
                q = robot.home.copy()
                q[j] = side * (bound - gap)
                dq = np.zeros(robot.n_joints)
                dq[j] = side * speed
                state = RobotState.legged(1, robot.n_joints, robot.n_feet, 25.0)
                state.q[:], state.dq[:] = q, dq
                guard.reset(state.q)
                for past in np.linspace(-gap - 0.3, limit - bound + gap + 0.5, 25):
                    t = bound - gap + past  # mirrored coordinates: toward the limit is +
                    target = np.tile(robot.home, (1, 1))
                    target[0, j] = side * t
                    out = guard.filter(target.copy(), state, out=np.empty_like(target))
                    d = c[pb.TOWARD if side > 0 else pb.TOWARD + 1, j]  # as the filter set it
                    qs, vs, tau = exact(bound - gap, speed, t, inertia, kp, kd, d, period)
                    if tau > min(effort, stall * (1.0 - (abs(speed) + 3.0) / no_load)):
                        continue  # saturated: not the closed form's joint
                    room = max(bound - qs[-1], 0.0)
                    brake = pb.BRAKE_SHARE * (effort - d) / inertia
                    stop = math.sqrt(2.0 * brake * room)
                    if qs.max() < bound - DECISIVE and vs[-1] < SPEED_SHARE * stop:
                        assert out[0, j] == target[0, j], (side, gap, speed, t)
                        passed += 1
                    elif qs.max() > bound + DECISIVE or vs[-1] > stop / SPEED_SHARE:
                        r = side * out[0, j]
                        assert r < t, (side, gap, speed, t)
                        qr, vr, _ = exact(bound - gap, speed, r, inertia, kp, kd, d, period)
                        assert qr.max() < bound + DECISIVE, (side, gap, speed, t, r)
                        stop = math.sqrt(2.0 * brake * max(bound + DECISIVE - qr[-1], 0.0))
                        assert vr[-1] < stop / SPEED_SHARE + 1e-9, (side, gap, speed, t, r)
                        changed += 1
    assert passed > 30 and changed > 30  # both sides of the decision were tried
