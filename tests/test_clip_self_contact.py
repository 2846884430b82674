"""A reference motion's own self-contacts (the clip posed in the robot's collision model) are
counted apart from the robot's: a contact the clip itself makes at that moment is not a
violation; one the clip does not make is."""

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.monitors.violations import ViolationMonitor
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.deploy.tasks.motion.self_contact import clip_self_contacts
from tests.test_violations import place


def _colliding(robot) -> np.ndarray:
    guard = SafetyGuard(robot, 1, "position")
    rng = np.random.default_rng(0)
    return next(
        q
        for q in rng.uniform(robot.soft_lower, robot.soft_upper, (500, robot.n_joints))
        if guard._in_collision(q)
    )


def test_the_clips_own_contact_is_counted_apart_and_a_policys_is_a_violation(arm6):
    """A 2.5 s reference at 10 Hz that passes through a contact in frames 10-14: the pre-screen
    finds those frames (and its depth, its pairs); a robot in that contact while the reference
    is at frame 12 is the reference's contact (no violation), the same contact while the
    reference stands at frame 0, out of its 0.1 s window, is a violation."""
    touch = _colliding(arm6)
    poses = np.array([arm6.home] * 10 + [touch] * 5 + [arm6.home] * 10)
    contacts = clip_self_contacts(arm6, poses, fps=10.0, window_s=0.1)
    summary = contacts.summary()
    assert summary["frames"] == 25 and summary["frames_touching"] == 5
    assert summary["worst_depth_m"] > 0.0 and summary["pairs"]
    assert contacts.allowed(9).any() and not contacts.allowed(8).any()  # one frame of window

    backend = SimBackend(arm6, mode="position", envs=2)
    for e in (0, 1):
        place(backend, e, touch)
    monitor = ViolationMonitor(arm6, 2)
    moments = {0: 12, 1: 0}  # env 0 dances through the clip's contact; env 1's clip is apart
    monitor.excuse_contacts(lambda e: contacts.allowed(moments[e]))
    monitor.update(backend)
    assert monitor.counts["self_collision"].tolist() == [0, 1]
    assert monitor.reference_ticks.tolist() == [1, 0]
    assert set(monitor.reference_pair_counts(0)) <= set(summary["pairs"])
    assert monitor.pair_counts(0) == {} and monitor.pair_counts(1)

    monitor.excuse_contacts(lambda e: None)  # no clip playing: every contact is the robot's
    monitor.update(backend)
    assert monitor.counts["self_collision"].tolist() == [1, 2]
