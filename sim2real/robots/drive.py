"""A robot with another drive: its joints' PD gains and its home pose replaced
(:func:`with_drive`).

The plant's position servos (``Robot.mjspec``: MuJoCo ``position`` actuators with ``kp``, ``kd``)
and every stage that starts from or returns to the home pose (the plant's reset, the runtime's
ramp-in and safe stop, the guard's last valid target) read these from the Robot, so a robot
derived here runs a policy with the gains and default pose it was trained with
(``deploy-run``; :mod:`sim2real.deploy.spec.drive`). Everything else (limits, motors, sensors, the MJCF)
is the robot's own.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from sim2real.robots.robot import Robot, RobotSpecError


def with_drive(
    robot: Robot,
    kp: Sequence[float] | None = None,
    kd: Sequence[float] | None = None,
    home: Sequence[float] | None = None,
    kinds: Sequence[str] | None = None,
) -> Robot:
    """``robot`` with its joints' ``kp`` (N m/rad), ``kd`` (N m s/rad) and its ``control.home``
    (rad) replaced, one value per joint in ``robot.joint_names`` order (None or empty: kept);
    ``kinds``: each joint's drive, ``"position"`` or ``"velocity"`` (a speed target, kp 0).

    The derived robot's ``description_hash`` is that of its changed description.

    Raises:
        RobotSpecError: a length other than one per joint, a ``kp`` that is not positive (not 0
            for a velocity drive), a
            ``kd`` that is negative, a home pose outside the joint limits (naming the joint).
    """
    n = robot.n_joints
    where = f"{robot.directory / 'robot.toml'} with the policy's drive"
    values = {}
    for name, given in (("kp", kp), ("kd", kd), ("home", home)):
        if given is None or len(given) == 0:
            continue
        arr = np.asarray(given, dtype=float)
        if arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise RobotSpecError(f"{where}: {name} needs {n} finite values, got {list(given)}")
        values[name] = arr
    cfg = robot.config
    if kinds:
        if len(kinds) != n or set(kinds) - {"position", "velocity"}:
            raise RobotSpecError(
                f"{where}: kinds needs {n} entries of 'position' or 'velocity', got {list(kinds)}"
            )
        velocity = np.array([k == "velocity" for k in kinds])
    else:
        velocity = np.array([j.drive == "velocity" for j in cfg.joints])
    kp_now = values.get("kp", np.array([j.kp for j in cfg.joints]))
    if np.any(np.where(velocity, kp_now != 0, kp_now <= 0)):
        raise RobotSpecError(
            f"{where}: kp must be positive (0 for a velocity drive), got {kp_now.tolist()}"
        )
    if "kd" in values and np.any(values["kd"] < 0):
        raise RobotSpecError(f"{where}: kd must be >= 0, got {values['kd'].tolist()}")
    if "home" in values:
        h = values["home"]
        out = np.flatnonzero((h < robot.position_lower) | (h > robot.position_upper))
        if out.size:
            i = int(out[0])
            raise RobotSpecError(
                f"{where}: home {h[i]} rad of joint '{robot.joint_names[i]}' is outside its "
                f"limits [{robot.position_lower[i]}, {robot.position_upper[i]}]"
            )
    joints = [
        j.model_copy(
            update={k: float(values[k][i]) for k in ("kp", "kd") if k in values}
            | ({"drive": kinds[i]} if kinds else {}),
        )
        for i, j in enumerate(cfg.joints)
    ]
    control = cfg.control
    if "home" in values:
        control = control.model_copy(update={"home": values["home"].tolist()})
    derived = cfg.model_copy(update={"joints": joints, "control": control})
    from sim2real.robots.loading import description_hash

    mjcf = (robot.directory / cfg.mjcf).resolve()
    home_array = np.array(derived.control.home, dtype=float)
    home_array.setflags(write=False)
    return dataclasses.replace(
        robot,
        config=derived,
        home=home_array,
        description_hash=description_hash(derived, mjcf.read_bytes()),
    )
