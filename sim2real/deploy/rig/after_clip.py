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

The third way (``--after-clip default-pose``, :data:`DEFAULT_POSE`): no second policy. At the
clip's end the policy is off (:class:`PolicyOff`, its output discarded) and the PD loop holds the
home pose (the policy's default joint pose), reached along a line from the last PD target over
``blend_s`` s (2 by default), as Unitree's own deploy holds a humanoid before and between policies
(unitree_rl_gym ``deploy/deploy_real/deploy_real.py``: ``move_to_default_pos``, ``total_time = 2``,
then ``default_pos_state``), with the run's gains (the policy's drive, not that config's kp/kd).
It is the runtime's RAMP_IN line (:meth:`Runtime.ramp_in
<sim2real.deploy.runtime.loop.Runtime.ramp_in>`, ``running=True``) run while the env stays
RUNNING: leaving RUNNING would end the clip's play in the tracking task (the base then unjudged
after it), and RAMP_IN's own end hands the robot back to the policy. Falls, the guard and the
base's travel after the clip are judged as after a hold.

One robot (``--envs 1``): the runtime has one policy for all its envs.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.rig.hooks import RunHook

#: ``--after-clip``'s name of the hold at the home pose with the policy off (module docstring)
DEFAULT_POSE = "default-pose"
#: s of the ramp to home of :data:`DEFAULT_POSE` (unitree_rl_gym
#: ``deploy/deploy_real/deploy_real.py``, ``move_to_default_pos``: ``total_time = 2``)
DEFAULT_POSE_RAMP_S = 2.0


class PolicyOff:
    """The policy off: ``spec`` (the outgoing policy's, its observation still built) and an
    action of zeros ((envs, n) float32) the runtime's ramp to home replaces
    (:meth:`Runtime.ramp_in <sim2real.deploy.runtime.loop.Runtime.ramp_in>`, ``running``)."""

    def __init__(self, spec, envs: int):
        self.spec = spec
        self.action = np.zeros((envs, spec.act_dim), dtype=np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.action


class AfterClipHook(RunHook):
    """Hand the runtime to ``policy`` (named ``name``) once the clip of ``rig``'s tracking task
    has played (module docstring), blended over ``blend_s`` s; ``policy`` None: the policy off,
    home held, ramped to over ``blend_s`` s (:data:`DEFAULT_POSE`).

    Attributes:
        at_s: s, the runtime's time of the hand-over (None before it).
    """

    name = "after_clip"

    def __init__(self, rig, policy, name: str, blend_s: float = 0.0):
        self.rig, self.policy, self.policy_name, self.blend_s = rig, policy, name, float(blend_s)
        self.at_s: float | None = None
        if policy is None:  # DEFAULT_POSE: the policy off, home held (module docstring)
            rig.task.follows("default_pose", None, self.blend_s)
        else:
            rig.task.follows("handover", name, self.blend_s)

    def after_tick(self, runtime) -> None:
        if self.at_s is not None:
            return
        task = self.rig.task
        done = task.motion.finished() & (runtime.mode == RUNNING)
        if not done.any():
            return
        if self.policy is None:
            runtime.switch_policy(PolicyOff(runtime.spec, runtime.envs))
            runtime.ramp_in(self.blend_s, done, running=True)
        else:
            runtime.switch_policy(self.policy, self.blend_s)
        task.hand_over(np.ones(task.envs, dtype=bool))
        self.at_s = float(runtime.time)

    def contribute(self, report: dict) -> None:
        tracking = report.get("tracking")
        if tracking is not None:
            tracking["after_clip"]["at_s"] = self.at_s
