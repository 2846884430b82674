"""The pose errors of the motion-tracking task: the body groups of the joint-angle error and the
bodies' position error (MPJPE), root-relative, by Pinocchio's forward kinematics."""

from __future__ import annotations

import numpy as np

#: Body groups of the joint-angle error, by a word of the joint's name (the first that matches).
GROUPS = (("legs", ("hip", "knee", "ankle")), ("waist", ("waist", "torso")), ("arms", ("",)))


def body_groups(joint_names) -> dict[str, np.ndarray]:
    """``{group: joint indices}`` of :data:`GROUPS` (a group with no joints left out)."""
    out: dict[str, list[int]] = {g: [] for g, _ in GROUPS}
    for i, name in enumerate(joint_names):
        group = next(g for g, words in GROUPS if any(w in name for w in words))
        out[group].append(i)
    return {g: np.array(v, dtype=np.intp) for g, v in out.items() if v}


class BodyPositions:
    """The bodies the joints of ``robot`` move (its Pinocchio model's BODY frames past the root
    joint), placed by forward kinematics with the base at the origin.

    Attributes:
        count: How many bodies.
    """

    def __init__(self, robot):
        import pinocchio as pin

        model = robot.pin_model
        self.robot = robot
        self._pin = (pin, model, model.createData())
        self._bodies = [
            i
            for i, f in enumerate(model.frames)
            if f.type == pin.FrameType.BODY and f.parentJoint > 1
        ]
        self.count = len(self._bodies)

    def at(self, q: np.ndarray) -> np.ndarray:
        """(count, 3) m: the bodies' positions at joint angles ``q`` (n,) rad."""
        pin, model, data = self._pin
        pin.framesForwardKinematics(model, data, self.robot.pin_configuration(q))
        return np.array([data.oMf[f].translation for f in self._bodies])

    def mpjpe(self, q_ref: np.ndarray, q: np.ndarray) -> float:
        """m: mean distance of the bodies of ``q_ref`` and ``q`` (n,) rad, base at the origin."""
        return float(np.linalg.norm(self.at(q_ref) - self.at(q), axis=1).mean())
