"""The hand-over at a clip's end (:class:`AfterClipHook`): a dance's policy gives the robot to
another policy once its clip has played, as rl_sar's G1 state machine does.

rl_sar (``src/rl_sar/fsm_robot/fsm_g1.hpp``, ``RLFSMStateRLWholeBodyTrackingDance102::Run`` and
``...GangnamStyle::Run``): once ``motion_time / motion_length == 1`` it requests
``RLFSMStateRLRoboMimicLocomotion``, whose ``Enter`` loads the locomotion policy and whose
``Run`` runs it at once (its ``Interpolate`` from the last pose is commented out): no blend. Here
the tracking task's clock reaching the clip's end (:meth:`MotionClock.finished
<sim2real.deploy.tasks.motion.clock.MotionClock.finished>`) switches the runtime's policy
(:meth:`Runtime.switch_policy <sim2real.deploy.runtime.loop.Runtime.switch_policy>`, over
``blend_s`` s: 0, rl_sar's, by default) for the rest of the run; the clip does not start again
(:meth:`TrackingTask.hand_over <sim2real.deploy.tasks.motion.tracking.TrackingTask.hand_over>`),
and the base is judged after the clip as after a hold (the tracking task's ``travel``).

One robot (``--envs 1``): the runtime has one policy for all its envs.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.rig.hooks import RunHook


class AfterClipHook(RunHook):
    """Hand the runtime to ``policy`` (named ``name``) once the clip of ``rig``'s tracking task
    has played (module docstring), blended over ``blend_s`` s.

    Attributes:
        at_s: s, the runtime's time of the hand-over (None before it).
    """

    name = "after_clip"

    def __init__(self, rig, policy, name: str, blend_s: float = 0.0):
        self.rig, self.policy, self.policy_name, self.blend_s = rig, policy, name, float(blend_s)
        self.at_s: float | None = None
        rig.task.follows("handover", name, self.blend_s)

    def after_tick(self, runtime) -> None:
        if self.at_s is not None:
            return
        task = self.rig.task
        done = task.motion.finished() & (runtime.mode == RUNNING)
        if not done.any():
            return
        runtime.switch_policy(self.policy, self.blend_s)
        task.hand_over(np.ones(task.envs, dtype=bool))
        self.at_s = float(runtime.time)

    def contribute(self, report: dict) -> None:
        tracking = report.get("tracking")
        if tracking is not None:
            tracking["after_clip"]["at_s"] = self.at_s
