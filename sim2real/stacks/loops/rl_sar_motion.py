"""rl_sar's motion side for the bare tracking loop (:mod:`.rl_sar_tracking`).

Written from rl_sar e384912 (read, not copied): ``motion_loader/motion_loader.cpp`` and
``vector_math/vector_math.hpp`` (quaternions ``w x y z``), ``rl_sdk.cpp`` ``ReadYaml`` (a
folder's ``config.yaml`` entries laid over ``base.yaml``'s). Its semantics, kept as they are:

- the CSV row: root position x y z, root quaternion **x y z w**, then the joints in SDK motor
  order; velocities the forward difference ``(q[i+1] - q[i]) / dt``, the last row repeating the
  one before;
- the clip's rate is not the file's: ``fsm_g1.hpp`` builds the loader at ``1 / (dt *
  decimation)`` (50 Hz for the G1), one frame per policy tick, whatever the file's name says;
- ``duration = frames * dt`` (not ``frames - 1``) and ``Update(t)`` maps
  ``t / duration * (frames - 1)`` to a frame: the clip's last frame comes at ``duration``;
- the anchor (torso) ``root * Rz(waist_yaw) * Rx(waist_roll) * Ry(waist_pitch)`` (waist in SDK
  slots 12, 13, 14 of the clip), the robot's the same from the IMU and its waist joints;
- ``Reset``: ``init = yaw(robot torso) * conj(yaw(clip torso at t=0))``, the yaw by
  ``atan2(2(wz + xy), 1 - 2(y^2 + z^2))``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml


def quat_mul(a, b) -> np.ndarray:
    """Hamilton product of ``w x y z`` quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def quat_conj(q) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_axis_angle(axis, angle: float) -> np.ndarray:
    return np.concatenate([[np.cos(angle / 2)], np.asarray(axis, float) * np.sin(angle / 2)])


def quat_angle(q) -> float:
    """rad, the rotation angle of ``q`` (0..pi)."""
    return float(2.0 * np.arccos(np.clip(abs(q[0]) / np.linalg.norm(q), 0.0, 1.0)))


def yaw_only(q) -> np.ndarray:
    """``QuaternionYawOnly``: the heading of ``q`` as a rotation about z."""
    yaw = np.arctan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def torso_quat(base_quat, waist) -> np.ndarray:
    """``ComputeTorsoQuat``: base * Rz(yaw) * Rx(roll) * Ry(pitch), normalised."""
    q = quat_mul(base_quat, quat_axis_angle([0, 0, 1], waist[0]))
    q = quat_mul(q, quat_axis_angle([1, 0, 0], waist[1]))
    q = quat_mul(q, quat_axis_angle([0, 1, 0], waist[2]))
    return q / np.linalg.norm(q)


def slerp(q0, q1, t: float) -> np.ndarray:
    """``MotionLoader::Slerp``: the short way, linear (normalised) above a dot of 0.9995."""
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -np.asarray(q1), -dot
    if dot > 0.9995:
        q = np.asarray(q0) + t * (np.asarray(q1) - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    s = np.sin(theta)
    return (np.sin((1 - t) * theta) * np.asarray(q0) + np.sin(t * theta) * np.asarray(q1)) / s


def robot_dir(folder: Path) -> Path:
    """``policy/<robot>``: the nearest parent of ``folder`` holding ``base.yaml``."""
    for parent in Path(folder).resolve().parents:
        if (parent / "base.yaml").is_file():
            return parent
    raise FileNotFoundError(f"{folder}: no base.yaml in a parent folder")


def rl_sar_params(folder: Path) -> tuple[dict, dict]:
    """(base.yaml's robot section, that laid under config.yaml's section) of an rl_sar folder
    ``policy/<robot>/<task...>``: base.yaml is ``policy/<robot>/base.yaml``, keyed ``<robot>``;
    config.yaml keyed ``<robot>/<task...>`` (``ReadYaml``'s ``config_path`` key)."""
    folder = Path(folder).resolve()
    robot = robot_dir(folder)
    key = f"{robot.name}/{folder.relative_to(robot).as_posix()}"
    base = yaml.safe_load((robot / "base.yaml").read_text())[robot.name]
    config = yaml.safe_load((folder / "config.yaml").read_text())[key]
    return base, {**base, **config}


class RlSarMotion:
    """``MotionLoader``: the clip at ``fps`` (rl_sar passes the control rate), its clock and
    the yaw alignment. Joint arrays in the CSV's (SDK motor) order."""

    def __init__(self, path, fps: float, waist=(12, 13, 14)):
        rows = np.loadtxt(path, delimiter=",", ndmin=2)
        self.root_pos = rows[:, 0:3]
        self.root_quat = rows[:, [6, 3, 4, 5]]  # x y z w -> w x y z
        self.joints = rows[:, 7:]
        self.dt = 1.0 / fps
        vel = np.diff(self.joints, axis=0) / self.dt
        self.velocities = np.vstack([vel, vel[-1:]])
        self.frames = len(rows)
        self.duration = self.frames * self.dt
        self.waist = list(waist)
        self.init_quat = np.array([1.0, 0.0, 0.0, 0.0])
        self.update(0.0)

    def update(self, time: float) -> None:
        frame = float(np.clip(time / self.duration, 0.0, 1.0)) * (self.frames - 1)
        self.i0 = int(np.floor(frame))
        self.i1 = min(self.i0 + 1, self.frames - 1)
        self.blend = frame - self.i0

    def joint_pos(self) -> np.ndarray:
        return self.joints[self.i0] * (1 - self.blend) + self.joints[self.i1] * self.blend

    def joint_vel(self) -> np.ndarray:
        return self.velocities[self.i0] * (1 - self.blend) + self.velocities[self.i1] * self.blend

    def root(self) -> np.ndarray:
        return slerp(self.root_quat[self.i0], self.root_quat[self.i1], self.blend)

    def anchor_quat(self) -> np.ndarray:
        """The clip's torso (``GetAnchorQuat``), w x y z, in the recording's frame."""
        return torso_quat(self.root(), self.joint_pos()[self.waist])

    def aligned_anchor_quat(self) -> np.ndarray:
        """``init * anchor``: the clip's torso turned to the robot's heading at ``reset``."""
        return quat_mul(self.init_quat, self.anchor_quat())

    def reset(self, robot_base_quat, robot_waist) -> None:
        """``Reset``: clock to 0, ``init = yaw(robot torso) * conj(yaw(clip torso))``."""
        self.update(0.0)
        robot = torso_quat(np.asarray(robot_base_quat, float), robot_waist)
        self.init_quat = quat_mul(yaw_only(robot), quat_conj(yaw_only(self.anchor_quat())))
