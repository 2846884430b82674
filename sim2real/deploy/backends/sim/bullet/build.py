"""A robot's compiled MuJoCo model rebuilt as a pybullet world: the bodies, joints, inertias,
collision geometry, contact filter, floor friction and joint limits of that one model.

The plant builds its pybullet world from the very ``MjModel`` the MuJoCo plant would step (one per
env, randomized by the soak), so link masses and lengths, joint friction and damping, floor
friction and added payloads reach both engines alike. What pybullet cannot hold is mapped:

- **Armature** (a drive's reflected rotor inertia, ``dof_armature``): pybullet's multibodies have
  none. A fixed-base arm gets it exactly, in joint space, from the plant's torques
  (``BulletBackend._armature_torque``). A floating base (whose contacts make that inexact) gets a
  rotor link per drive, geared to its joint (:data:`ROTOR_GEAR_RATIO`).
- **Friction pairs** and the **contact filter**: MuJoCo's rules
  (:mod:`sim2real.deploy.backends.sim.bullet.contacts`) as link frictions and pybullet pair filters.
- Joint dry friction (``dof_frictionloss``) is pybullet's zero-velocity motor with that maximum
  torque; damping and the drives are the plant's explicit torques (:mod:`.world`).

Geoms and inertias: :mod:`sim2real.deploy.backends.sim.bullet.convert`. Each body holds at most
one hinge or slide joint (or none: a fixed link).

Errors: :class:`~sim2real.deploy.backends.sim.bullet.convert.UnsupportedModelError` names the
body, joint or geom pybullet cannot build.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pybullet as pb

from sim2real.deploy.backends.sim.bullet.contacts import (
    bodies_collide,
    floor_friction,
    geoms_collide,
)
from sim2real.deploy.backends.sim.bullet.convert import (
    UnsupportedModelError,
    body_geoms,
    collision_shape,
    geom_shape,
    inertial_frame,
    quat_to_mat,
    wxyz,
    xyzw,
)

#: A legged robot's drives: each armature is a rotor link of ``armature / ROTOR_GEAR_RATIO^2``
#: geared ``ROTOR_GEAR_RATIO`` to its joint (a bullet gear constraint). MuJoCo's armature is the
#: limit of an infinite ratio; at 30 the cross terms a rotor adds to the joints upstream are 3 %
#: of its armature, and bullet's solver still resolves the gear within a step.
ROTOR_GEAR_RATIO = 30.0
#: kg, a rotor link's mass (it must have one; small against any link's).
ROTOR_MASS = 1e-4


#: createMultiBody's per-link arguments, in the order of ``_Tree.link_args``.
_LINK_FIELDS = (
    "linkMasses",
    "linkCollisionShapeIndices",
    "linkPositions",
    "linkOrientations",
    "linkInertialFramePositions",
    "linkInertialFrameOrientations",
    "linkParentIndices",
    "linkJointTypes",
    "linkJointAxis",
)


_JOINT = {
    int(mujoco.mjtJoint.mjJNT_HINGE): pb.JOINT_REVOLUTE,
    int(mujoco.mjtJoint.mjJNT_SLIDE): pb.JOINT_PRISMATIC,
}


@dataclass
class BulletWorld:
    """One env's pybullet world, as :func:`build_world` made it.

    Attributes:
        client: pybullet physics client id (a DIRECT connection of its own).
        body: Multibody id of the robot.
        link_of_body: (nbody,) int, MuJoCo body id -> pybullet link index (-1 the base, -2 a
            body outside the robot: the world).
        joint_index: (n_joints,) pybullet joint indices of the robot's joints, in MuJoCo order.
        com_offset: (3,) m, the base's centre of mass in its MuJoCo body frame (pybullet reports
            the base's pose at its inertial frame); zeros for a fixed base.
        com_quat: (4,) (w, x, y, z) the base's inertial frame in its body frame.
        floating: The robot's base is a free joint.
        rotor_index: (n_joints,) pybullet joint index of each joint's rotor link (-1: none),
            geared ``ROTOR_GEAR_RATIO`` to it.
    """

    client: int
    body: int
    link_of_body: np.ndarray
    joint_index: list[int]
    com_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    com_quat: np.ndarray = field(default_factory=lambda: np.array([1.0, 0, 0, 0]))
    floating: bool = False
    rotor_index: list[int] = field(default_factory=list)


def change_dynamics(client: int, body: int, link: int, **fields) -> None:
    """``pybullet.changeDynamics`` one field a call: given several fields at once, pybullet 3.2
    silently keeps only some (a link's inertia given with its damping is dropped, joint limits
    given with the maximum joint velocity too). ``jointLimits``: (lower, upper), set together."""
    for name, value in fields.items():
        if name == "jointLimits":
            pb.changeDynamics(
                body,
                link,
                jointLowerLimit=value[0],
                jointUpperLimit=value[1],
                physicsClientId=client,
            )
        else:
            pb.changeDynamics(body, link, **{name: value}, physicsClientId=client)


def build_world(m: mujoco.MjModel, root: int, n_joints: int, floating: bool) -> BulletWorld:
    """Build ``m``'s robot in a new pybullet DIRECT client (module docstring).

    Args:
        m: The compiled model (with the plant's timestep and gravity).
        root: MuJoCo body id of the robot's root (the floating base, or the fixed base).
        n_joints: The robot's actuated joints (MuJoCo's joints after a free joint).
        floating: The root has a free joint.

    Returns:
        The world, its robot at the model's reference pose (``qpos0``), at rest.

    Raises:
        UnsupportedModelError: a geom type, a body with several joints or a ball joint.
    """
    client = pb.connect(pb.DIRECT)
    try:
        with tempfile.TemporaryDirectory(prefix="bullet-meshes-") as meshdir:  # read at creation
            return _build(client, m, root, n_joints, floating, Path(meshdir))
    except Exception:
        pb.disconnect(client)
        raise


def _anchor(m: mujoco.MjModel, b: int) -> np.ndarray:
    """The link frame's origin in body ``b``'s frame: its joint's anchor (zeros for none)."""
    if m.body_jntnum[b] == 0:
        return np.zeros(3)
    j = int(m.body_jntadr[b])
    if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE):
        return np.zeros(3)
    return m.jnt_pos[j].copy()


def _build(client: int, m: mujoco.MjModel, root: int, n_joints: int, floating: bool, meshdir: Path):
    pb.setGravity(*m.opt.gravity.tolist(), physicsClientId=client)
    pb.setPhysicsEngineParameter(
        fixedTimeStep=float(m.opt.timestep), numSubSteps=0, physicsClientId=client
    )
    # the bodies of the robot: the root's subtree, in MuJoCo's (parents first) order
    robot = [b for b in range(m.nbody) if b == root or _descends(m, b, root)]
    tree = _Tree(m, robot, meshdir)
    rotors = (
        {r.body: r for r in _rotors(m, robot[1:], tree.axes, tree.placement)} if floating else {}
    )
    tree.order_links(root, rotors)
    self_collision = any(
        bodies_collide(m, a, b) for i, a in enumerate(robot) for b in robot[i + 1 :]
    )
    body = _create_body(client, m, root, floating, tree, self_collision)
    joint_index = _set_dynamics(client, m, body, tree)
    if len(joint_index) != n_joints:
        raise UnsupportedModelError(
            f"the model has {len(joint_index)} hinge or slide joints; the robot has {n_joints}"
        )
    if self_collision:
        _filter_pairs(client, m, body, robot, tree.link_of_body)
    _build_world_geoms(client, m, body, robot, tree.link_of_body, meshdir)
    rotor_index = _gear_rotors(client, body, rotors, tree, joint_index)
    inertial = tree.inertials[root]
    com = np.asarray(inertial[0]) if floating else np.zeros(3)
    com_quat = wxyz(inertial[1]) if floating else np.array([1.0, 0, 0, 0])
    return BulletWorld(
        client, body, tree.link_of_body, joint_index, com, com_quat, floating, rotor_index
    )


class _Tree:
    """The robot's bodies as pybullet links: each link's joint kind and axis, its placement in
    its parent's link frame, its inertial frame and shapes, and (:meth:`order_links`) pybullet's
    link order with the rotors.

    Raises:
        UnsupportedModelError: a body with several joints, or a joint neither hinge nor slide.
    """

    def __init__(self, m: mujoco.MjModel, robot: list[int], meshdir: Path):
        self.m, self.robot = m, robot
        self.anchors = {b: _anchor(m, b) for b in robot}
        self.shapes = {
            b: [s for g in body_geoms(m, b) if (s := geom_shape(m, g, self.anchors[b], meshdir))]
            for b in robot
        }
        self.inertials = {b: inertial_frame(m, b, self.anchors[b]) for b in robot}
        self.kinds, self.axes = {}, {}  # per link body
        for b in robot[1:]:
            self.kinds[b], self.axes[b] = _link_joint(m, b)

    def placement(self, b: int) -> tuple[list, list]:
        """Link frame of ``b`` in its parent's link frame: (position, xyzw orientation)."""
        parent = int(self.m.body_parentid[b])
        rot = quat_to_mat(self.m.body_quat[b])
        pos = self.m.body_pos[b] + rot @ self.anchors[b] - self.anchors[parent]
        return pos.tolist(), xyzw(self.m.body_quat[b])

    def order_links(self, root: int, rotors: dict) -> None:
        """pybullet orders the links depth first, each link's children in the order given: a
        rotor goes just before the link it drives (its sibling), so that this order is
        pybullet's. Sets ``order``, ``link_of_body`` ((nbody,), -1 the base, -2 the world) and
        ``rotor_link`` (body -> its rotor's link)."""
        self.order: list = []
        for b in self.robot[1:]:
            if b in rotors:
                self.order.append(rotors[b])
            self.order.append(b)
        self.link_of_body = np.full(self.m.nbody, -2, dtype=np.int64)
        self.link_of_body[root] = -1
        self.rotor_link = {}
        for i, entry in enumerate(self.order):
            if isinstance(entry, _Rotor):
                self.rotor_link[entry.body] = i
            else:
                self.link_of_body[entry] = i

    def parent_of(self, entry) -> int:
        """createMultiBody's parent index of a body or a rotor (0 the base)."""
        b = entry.body if isinstance(entry, _Rotor) else entry
        return int(self.link_of_body[self.m.body_parentid[b]]) + 1

    def link_args(self, client: int, entry) -> tuple:
        """createMultiBody's per-link arguments of a body or a rotor, in ``_LINK_FIELDS`` order."""
        if isinstance(entry, _Rotor):
            return (
                ROTOR_MASS, -1, entry.position, entry.orientation, [0.0, 0.0, 0.0],
                entry.inertial_orientation, self.parent_of(entry), pb.JOINT_REVOLUTE, entry.axis,
            )  # fmt: skip
        position, orientation = self.placement(entry)
        inertial = self.inertials[entry]
        return (
            float(self.m.body_mass[entry]), collision_shape(client, self.shapes[entry]), position,
            orientation, inertial[0], inertial[1], self.parent_of(entry),
            self.kinds[entry], self.axes[entry],
        )  # fmt: skip


def _link_joint(m: mujoco.MjModel, b: int) -> tuple[int, list]:
    """Body ``b``'s pybullet joint type and unit axis (fixed for a body without a joint)."""
    if m.body_jntnum[b] > 1:
        raise UnsupportedModelError(
            f"body '{m.body(b).name}' has {m.body_jntnum[b]} joints; pybullet links take one"
        )
    if m.body_jntnum[b] == 0:
        return pb.JOINT_FIXED, [0.0, 0.0, 1.0]
    j = int(m.body_jntadr[b])
    if int(m.jnt_type[j]) not in _JOINT:
        raise UnsupportedModelError(
            f"joint '{m.joint(j).name}': type {mujoco.mjtJoint(m.jnt_type[j]).name} has no "
            "pybullet link joint here (expected hinge or slide)"
        )
    return _JOINT[int(m.jnt_type[j])], (m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j])).tolist()


def _create_body(client, m, root: int, floating: bool, tree: _Tree, self_collision: bool) -> int:
    """The robot's multibody at the model's reference pose; its link order checked against
    ``tree.order`` (``UnsupportedModelError`` if pybullet reordered them)."""
    args = [tree.link_args(client, entry) for entry in tree.order]
    per_link = {name: [a[k] for a in args] for k, name in enumerate(_LINK_FIELDS)}
    root_pos, root_quat = m.body_pos[root] + tree.anchors[root], m.body_quat[root]
    if floating:  # the free joint's reference pose
        a = int(m.jnt_qposadr[int(m.body_jntadr[root])])
        root_pos, root_quat = m.qpos0[a : a + 3], m.qpos0[a + 3 : a + 7]
    inertial = tree.inertials[root]
    body = pb.createMultiBody(
        baseMass=float(m.body_mass[root]) if floating else 0.0,
        baseCollisionShapeIndex=collision_shape(client, tree.shapes[root]),
        basePosition=np.asarray(root_pos).tolist(),
        baseOrientation=xyzw(np.asarray(root_quat)),
        baseInertialFramePosition=inertial[0],
        baseInertialFrameOrientation=inertial[1],
        linkVisualShapeIndices=[-1] * len(tree.order),
        **per_link,
        flags=pb.URDF_USE_SELF_COLLISION if self_collision else 0,
        physicsClientId=client,
    )
    for i, entry in enumerate(tree.order):
        got = pb.getJointInfo(body, i, physicsClientId=client)[16]
        if got != tree.parent_of(entry) - 1:
            raise UnsupportedModelError(
                f"pybullet reordered the links of body '{m.body(root).name}' (link {i}: parent "
                f"{got}, expected {tree.parent_of(entry) - 1}); expected MuJoCo's depth-first order"
            )
    return body


def _set_dynamics(client: int, m: mujoco.MjModel, body: int, tree: _Tree) -> list[int]:
    """Exact inertias (createMultiBody derives them from the shapes), no extra damping, the
    joints' limits; returns the pybullet joint index of each MuJoCo hinge or slide, in order."""
    for b in tree.robot:
        change_dynamics(
            client,
            body,
            int(tree.link_of_body[b]),
            localInertiaDiagonal=tree.inertials[b][2],
            linearDamping=0.0,
            angularDamping=0.0,
            lateralFriction=1.0,
            restitution=0.0,
        )
    joint_index = []
    for j in range(m.njnt):
        if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE):
            continue
        link = int(tree.link_of_body[int(m.jnt_bodyid[j])])
        if link < 0:
            raise UnsupportedModelError(f"joint '{m.joint(j).name}' is outside the robot's tree")
        joint_index.append(link)
        change_dynamics(client, body, link, maxJointVelocity=1e3, jointDamping=0.0)
        if m.jnt_limited[j]:
            lo, hi = m.jnt_range[j]
            change_dynamics(client, body, link, jointLimits=(float(lo), float(hi)))
    return joint_index


def _filter_pairs(client: int, m: mujoco.MjModel, body: int, robot, link_of_body) -> None:
    """Self-collision off for every pair of the robot's bodies MuJoCo would not collide."""
    for i, a in enumerate(robot):
        for b in robot[i + 1 :]:
            if not bodies_collide(m, a, b):
                pb.setCollisionFilterPair(
                    body,
                    body,
                    int(link_of_body[a]),
                    int(link_of_body[b]),
                    0,
                    physicsClientId=client,
                )


def _gear_rotors(client: int, body: int, rotors: dict, tree: _Tree, joint_index) -> list[int]:
    """Each rotor's inertia and its gear constraint to its joint (velocities only); returns the
    rotor link of each joint (-1: none)."""
    rotor_index = [-1] * len(joint_index)
    for b, r in rotors.items():
        link, drives = tree.rotor_link[b], int(tree.link_of_body[b])
        rotor_index[joint_index.index(drives)] = link
        change_dynamics(
            client,
            body,
            link,
            localInertiaDiagonal=r.inertia,
            linearDamping=0.0,
            angularDamping=0.0,
            maxJointVelocity=1e6,
            jointDamping=0.0,
        )
        gear = pb.createConstraint(
            body,
            drives,
            body,
            link,
            jointType=pb.JOINT_GEAR,
            jointAxis=r.axis,
            parentFramePosition=[0.0, 0.0, 0.0],
            childFramePosition=[0.0, 0.0, 0.0],
            physicsClientId=client,
        )
        # velocities only (erp 0): the rotor's angle is free, only its speed is geared
        pb.changeConstraint(
            gear, gearRatio=1.0 / ROTOR_GEAR_RATIO, maxForce=1e9, erp=0.0, physicsClientId=client
        )
    if rotors:  # no motor of their own
        spinning = sorted(tree.rotor_link.values())
        pb.setJointMotorControlArray(
            body,
            spinning,
            pb.VELOCITY_CONTROL,
            forces=[0.0] * len(spinning),
            physicsClientId=client,
        )
    return rotor_index


@dataclass
class _Rotor:
    """A drive's rotor link: on the joint's parent, at the joint, spinning about its axis."""

    body: int  # MuJoCo body whose joint it is geared to
    position: list
    orientation: list
    axis: list
    inertial_orientation: list
    inertia: list


def _rotors(m: mujoco.MjModel, links: list[int], axes: dict, placement) -> list[_Rotor]:
    """One rotor link per hinge with armature: ``armature / ROTOR_GEAR_RATIO^2`` about the axis,
    geared ``ROTOR_GEAR_RATIO`` to its joint, so that the joint feels the armature."""
    out = []
    for b in links:
        if m.body_jntnum[b] != 1:
            continue
        j = int(m.body_jntadr[b])
        armature = float(m.dof_armature[m.jnt_dofadr[j]])
        if int(m.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_HINGE) or armature <= 0.0:
            continue
        spin = armature / ROTOR_GEAR_RATIO**2
        z_to_axis = np.empty(4)
        mujoco.mju_quatZ2Vec(z_to_axis, np.asarray(axes[b], dtype=np.float64))
        position, orientation = placement(b)
        out.append(
            _Rotor(
                body=b,
                position=position,
                orientation=orientation,
                axis=axes[b],
                inertial_orientation=xyzw(z_to_axis),
                inertia=[spin / 2, spin / 2, spin],
            )
        )
    return out


def _descends(m: mujoco.MjModel, b: int, root: int) -> bool:
    while b > 0:
        b = int(m.body_parentid[b])
        if b == root:
            return True
    return False


def _build_world_geoms(client, m, body, robot, link_of_body, meshdir: Path) -> None:
    """The geoms outside the robot (the floor, a table) as static bodies, each filtered against
    the robot's links by MuJoCo's rule, with the floor friction MuJoCo's rule gives."""
    mu = floor_friction(m)
    robot_set = set(robot)
    for b in range(m.nbody):
        if b in robot_set or (b != 0 and any(_descends(m, b, r) for r in robot)):
            continue
        if b != 0 and m.body_jntnum[b]:
            continue  # another moving body: not part of this plant
        for g in body_geoms(m, b):
            shape = geom_shape(m, g, np.zeros(3), meshdir)
            if shape is None:
                continue
            pos, quat = shape.pop("pos"), shape.pop("quat")
            col = pb.createCollisionShape(**shape, physicsClientId=client)
            world_pos = m.body_pos[b] + quat_to_mat(m.body_quat[b]) @ np.asarray(pos)
            world_quat = np.empty(4)
            mujoco.mju_mulQuat(world_quat, m.body_quat[b], wxyz(quat))
            static = pb.createMultiBody(
                baseMass=0.0,
                baseCollisionShapeIndex=col,
                basePosition=world_pos.tolist(),
                baseOrientation=xyzw(world_quat),
                physicsClientId=client,
            )
            change_dynamics(client, static, -1, lateralFriction=mu, restitution=0.0)
            for rb in robot:
                geoms = body_geoms(m, rb)
                if not any(geoms_collide(m, g, h) for h in geoms):
                    pb.setCollisionFilterPair(
                        static, body, -1, int(link_of_body[rb]), 0, physicsClientId=client
                    )
