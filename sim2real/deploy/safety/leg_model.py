"""The legs' one-joint model that the PD barrier (:mod:`sim2real.deploy.safety.pd_barrier`)
judges a target with: each joint's least inertia (:func:`least_inertia`), the joints on each
foot's chain (:func:`foot_chains`) and the joints whose motion toward a limit drives their foot
into the ground (:func:`pressing_joints`). Units: kg m^2, m/rad."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from sim2real.robots.continuous import sampling_bounds

#: Seeded poses, uniform within the joints' ranges, over which the least inertia is taken.
INERTIA_POSES = 63
#: m/rad: how far a joint's motion must move its foot down (the base frame's -z, at the home
#: pose) per radian toward a limit to count as pressing the foot into the ground
#: (:func:`pressing_joints`). Our choice: 0.05, under a Go2 knee's 0.10-0.14 (its extension
#: pushes a foot in stance into the ground: climbing a step, the policy's own loop holds its
#: rear knees there) and above a humanoid's knee's 0.03 and its ankle roll's 0 (a foot rolling
#: on its edge as it lifts off: the least inertia's case).
PRESS_LEVER = 0.05


def least_inertia(robot, poses: int = INERTIA_POSES, seed: int = 0) -> np.ndarray:
    """(n,) kg m^2: each joint's smallest effective inertia ``1 / (M^-1)_jj`` (``M``: the
    mass matrix, armature included, of the robot's fixed-base model: Pinocchio's CRBA, legs in
    the air) over its home pose and ``poses`` seeded poses uniform within the joints' ranges.
    ``tau / (M^-1)_jj`` is the joint's acceleration under a torque ``tau`` with the other
    joints free; the diagonal ``M_jj`` (the other joints locked) is up to 11 x it (an H1-2's
    hip roll) and under-predicts a PD target's motion over a control period
    (docs/measurements.md)."""
    model = robot.fixed_base_model
    data = model.createData()
    rng = np.random.default_rng(seed)
    lo, hi = sampling_bounds(robot.position_lower, robot.position_upper)  # a wheel: one turn
    least = np.full(robot.n_joints, np.inf)
    for q in [robot.home, *(rng.uniform(lo, hi) for _ in range(poses))]:
        m = pin.crba(model, data, np.asarray(q, dtype=np.float64))
        m = np.triu(m) + np.triu(m, 1).T  # CRBA fills the upper triangle
        least = np.minimum(least, 1.0 / np.diag(np.linalg.inv(m)))
    return least


def pressing_joints(robot) -> np.ndarray:
    """(2, n) float64: 1.0 where moving joint ``j`` toward its upper (row 0) or lower (row 1)
    limit moves the foot whose chain holds it down by more than ``PRESS_LEVER`` m per radian
    (the foot frame's Jacobian along the base's z axis at the home pose, the fixed-base model's:
    a foot in stance is driven into the ground, the body lifted); zeros for an arm. A Go2's
    knees press toward their upper limit (extension), its hips' abduction toward one limit each;
    a humanoid's ankle roll does not (its foot frame sits on the roll axis)."""
    model = robot.fixed_base_model
    data = model.createData()
    q = np.asarray(robot.home, dtype=np.float64)
    pin.computeJointJacobians(model, data, q)
    pin.framesForwardKinematics(model, data, q)
    out = np.zeros((2, robot.n_joints))
    chains = foot_chains(robot)
    for f, frame in enumerate(robot.foot_frame_ids):
        z = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[2]
        for j, name in enumerate(robot.joint_names):
            if chains[f, j] > 0.0:
                dz = z[model.joints[model.getJointId(name)].idx_v]
                out[0, j] = max(out[0, j], float(dz < -PRESS_LEVER))
                out[1, j] = max(out[1, j], float(dz > PRESS_LEVER))
    return out


def foot_chains(robot) -> np.ndarray:
    """(n_feet, n) float64: 1.0 where joint ``j`` is on the chain from the base to foot ``f``
    (Pinocchio's ``supports`` of the foot frame's parent joint); (0, n) for an arm."""
    model = robot.pin_model
    chains = np.zeros((robot.n_feet, robot.n_joints))
    index = {name: j for j, name in enumerate(robot.joint_names)}
    for f, frame in enumerate(robot.foot_frame_ids):
        for joint in model.supports[model.frames[frame].parentJoint]:
            j = index.get(model.names[joint])
            if j is not None:
                chains[f, j] = 1.0
    return chains
