"""Foxglove's well-known schemas for the MCAP telemetry (protobuf, ``foxglove-schemas-protobuf``).

Opening a telemetry file in Foxglove then shows the robot in the 3D panel and its joints in the
plot and log panels without a message definition to write:

``/tf`` ``foxglove.FrameTransforms``: one transform per link body and one for the end-effector
site, parent frame ``world`` (the robot's base frame), from Pinocchio forward kinematics of the
logged estimated joint positions (translation m, rotation a unit quaternion x, y, z, w);
``/robot`` ``foxglove.SceneUpdate``: the robot's geometry (MuJoCo boxes, cylinders, capsules,
spheres; meshes are left out) locked to those frames, once at the start;
``/joint_states`` ``foxglove.JointStates``: estimated position (rad) and velocity (rad/s);
``/joint_commands`` ``foxglove.JointStates``: the command written to the backend, as position
(rad), velocity (rad/s) or effort (N m) by the control mode;
``/guard_events`` ``foxglove.Log``: guard interventions (WARNING) and state-machine transitions
(safe stop and fault: ERROR, others INFO) since the previous sample.

With several envs every joint and frame name is prefixed ``env<k>/``.

Needs the ``foxglove`` extra (``foxglove-schemas-protobuf``); :func:`available` says whether it is
installed.
"""

from __future__ import annotations

import numpy as np

FRAME_TRANSFORMS = "foxglove.FrameTransforms"
JOINT_STATES = "foxglove.JointStates"
SCENE_UPDATE = "foxglove.SceneUpdate"
LOG = "foxglove.Log"
WORLD = "world"


def available() -> bool:
    """Whether ``foxglove-schemas-protobuf`` (the ``foxglove`` extra) is installed."""
    try:
        import foxglove_schemas_protobuf  # noqa: F401
    except ImportError:
        return False
    return True


def file_descriptor_set(message_class) -> bytes:
    """The serialized ``FileDescriptorSet`` of a protobuf message class and its dependencies
    (dependencies first): the MCAP schema data of a ``protobuf`` schema."""
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    fds, seen = FileDescriptorSet(), set()

    def add(fd) -> None:
        if fd.name in seen:
            return
        seen.add(fd.name)
        for dep in fd.dependencies:
            add(dep)
        fd.CopyToProto(fds.file.add())

    add(message_class.DESCRIPTOR.file)
    return fds.SerializeToString()


def _stamp(t_ns: int):
    from google.protobuf.timestamp_pb2 import Timestamp

    return Timestamp(seconds=t_ns // 1_000_000_000, nanos=t_ns % 1_000_000_000)


def rotation_to_quaternion(r: np.ndarray) -> tuple[float, float, float, float]:
    """(3, 3) rotation matrix -> unit quaternion (x, y, z, w), w >= 0."""
    import pinocchio as pin

    c = pin.Quaternion(np.asarray(r, dtype=np.float64)).coeffs()  # x, y, z, w
    if c[3] < 0:
        c = -c
    return float(c[0]), float(c[1]), float(c[2]), float(c[3])


class FoxgloveEncoder:
    """Builds the Foxglove messages of one telemetry sample.

    Args:
        robot: The :class:`~robots.Robot` (``pin_model``, ``joint_names``, ``ee_frame_id``,
            ``mjcf_path``).
        envs: Number of envs.
        control_mode: ``position``, ``velocity`` or ``torque``: the field of ``/joint_commands``.

    Raises:
        ImportError: ``foxglove-schemas-protobuf`` is not installed.
        ValueError: an unknown ``control_mode``.
    """

    def __init__(self, robot, envs: int, control_mode: str):
        import pinocchio as pin
        from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
        from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
        from foxglove_schemas_protobuf.Log_pb2 import Log
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

        fields = {"position": "position", "velocity": "velocity", "torque": "effort"}
        if control_mode not in fields:
            raise ValueError(f"control_mode: expected one of {tuple(fields)}, got {control_mode}")
        self.command_field = fields[control_mode]
        self.robot, self.envs = robot, envs
        self.classes = {
            FRAME_TRANSFORMS: FrameTransforms,
            JOINT_STATES: JointStates,
            LOG: Log,
            SCENE_UPDATE: SceneUpdate,
        }
        self.Log = Log
        self.model = robot.pin_model
        self.data = self.model.createData()
        self.frames = [
            (i, f.name)
            for i, f in enumerate(self.model.frames)
            if f.type == pin.FrameType.BODY or i == robot.ee_frame_id
        ]
        prefixes = [f"env{e}/" if envs > 1 else "" for e in range(envs)]
        self.prefixes = prefixes
        self.frame_names = [[p + name for _, name in self.frames] for p in prefixes]
        self.joint_names = [[p + name for name in robot.joint_names] for p in prefixes]

    @property
    def ee_frame(self) -> str:
        """Name of the end-effector site's frame (env 0)."""
        return self.frame_names[0][[i for i, _ in self.frames].index(self.robot.ee_frame_id)]

    def frame_transforms(
        self, t_ns: int, q: np.ndarray, base_orientation: np.ndarray | None = None
    ) -> bytes:
        """``/tf`` for joint positions ``q`` (envs, n) rad at ``t_ns`` ns: every link frame and
        the end-effector site in ``world``, by forward kinematics.

        A floating-base robot's base sits at the origin of ``world`` with ``base_orientation``
        ((envs, 4) unit quaternions ``[w, x, y, z]``, the base estimator's; default upright):
        the estimator knows the base's attitude, not its position."""
        import pinocchio as pin
        from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform

        msg = self.classes[FRAME_TRANSFORMS]()
        stamp = _stamp(t_ns)
        for e in range(self.envs):
            quat = None if base_orientation is None else base_orientation[e]
            configuration = self.robot.pin_configuration(q[e], None, quat)
            pin.framesForwardKinematics(self.model, self.data, configuration)
            for (fid, _), name in zip(self.frames, self.frame_names[e], strict=True):
                placement = self.data.oMf[fid]
                x, y, z = placement.translation
                qx, qy, qz, qw = rotation_to_quaternion(placement.rotation)
                tf = FrameTransform(parent_frame_id=WORLD, child_frame_id=name)
                tf.timestamp.CopyFrom(stamp)
                tf.translation.x, tf.translation.y, tf.translation.z = x, y, z
                tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = qx, qy, qz, qw
                msg.transforms.append(tf)
        return msg.SerializeToString()

    def joint_states(self, t_ns: int, position=None, velocity=None, effort=None) -> bytes:
        """A ``foxglove.JointStates`` of every env's joints; each of ``position`` (rad),
        ``velocity`` (rad/s), ``effort`` (N m) is None or (envs, n). Non-finite values are left
        unset."""
        msg = self.classes[JOINT_STATES]()
        msg.timestamp.CopyFrom(_stamp(t_ns))
        for e in range(self.envs):
            for j, name in enumerate(self.joint_names[e]):
                joint = msg.joints.add(name=name)
                for field, values in (
                    ("position", position),
                    ("velocity", velocity),
                    ("effort", effort),
                ):
                    if values is not None and np.isfinite(values[e, j]):
                        setattr(joint, field, float(values[e, j]))
        return msg.SerializeToString()

    def joint_commands(self, t_ns: int, command: np.ndarray) -> bytes:
        """``/joint_commands``: ``command`` (envs, n) in the field of the control mode."""
        return self.joint_states(t_ns, **{self.command_field: command})

    def log(self, t_ns: int, level: str, message: str) -> bytes:
        """A ``foxglove.Log`` (``level``: INFO, WARNING, ERROR) named ``guard``."""
        msg = self.Log(level=self.Log.Level.Value(level), message=message, name="guard")
        msg.timestamp.CopyFrom(_stamp(t_ns))
        return msg.SerializeToString()

    def scene(self, t_ns: int) -> bytes:
        """``/robot``: the robot's MuJoCo geoms (boxes, cylinders, capsules as cylinders,
        spheres; not meshes) as entities locked to the link frames of every env."""
        import mujoco
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

        m = mujoco.MjModel.from_xml_path(str(self.robot.mjcf_path))
        names = {name for _, name in self.frames}
        update = SceneUpdate()
        stamp = _stamp(t_ns)
        g = mujoco.mjtGeom
        for e in range(self.envs):
            for b in range(1, m.nbody):
                body = m.body(b).name
                if body not in names:
                    continue
                entity = update.entities.add(
                    frame_id=self.prefixes[e] + body,
                    id=f"{self.prefixes[e]}{body}",
                    frame_locked=True,
                )
                entity.timestamp.CopyFrom(stamp)
                for k in np.flatnonzero(m.geom_bodyid == b):
                    kind, size = m.geom_type[k], m.geom_size[k]
                    if kind == g.mjGEOM_BOX:
                        prim, dims = entity.cubes.add(), 2.0 * size
                    elif kind in (g.mjGEOM_CYLINDER, g.mjGEOM_CAPSULE):
                        prim = entity.cylinders.add()
                        extra = 2.0 * size[0] if kind == g.mjGEOM_CAPSULE else 0.0
                        dims = (2.0 * size[0], 2.0 * size[0], 2.0 * size[1] + extra)
                    elif kind == g.mjGEOM_SPHERE:
                        prim, dims = entity.spheres.add(), (2.0 * size[0],) * 3
                    else:
                        continue
                    x, y, z = m.geom_pos[k]
                    w, qx, qy, qz = m.geom_quat[k]
                    prim.pose.position.x, prim.pose.position.y, prim.pose.position.z = x, y, z
                    o = prim.pose.orientation
                    o.x, o.y, o.z, o.w = qx, qy, qz, w
                    prim.size.x, prim.size.y, prim.size.z = (float(v) for v in dims)
                    r, gr, bl, a = m.geom_rgba[k]
                    prim.color.r, prim.color.g, prim.color.b, prim.color.a = r, gr, bl, a
        return update.SerializeToString()
