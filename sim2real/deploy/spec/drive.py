"""The drive a policy was trained with: PD gains and default pose (:class:`DriveSpec`).

A position-mode policy learns the closed loop of its training simulator: the actuators' PD gains
(``tau = kp (target - q) - kd dq``) and the default pose its actions and joint observations are
relative to. Training stacks that write their contract into the ONNX file (mjlab, holosoma,
:mod:`sim2real.deploy.spec.foreign`) record both; a PolicySpec keeps them in ``drive`` (JSON key
``drive``, left out when empty), one entry per joint in the spec's ``joint_names`` order.

:func:`drive_differences` compares them with a robot's ``robot.toml`` (``kp``, ``kd``,
``control.home``); :func:`drive_robot` gives the robot that runs the policy's contract: the
simulated plant is built with the policy's gains and home pose (:func:`sim2real.robots.drive.with_drive`),
in ``deploy-run`` and in the soak; a backend that cannot set its drives' gains refuses differing
ones with the values (``sim2real.deploy.cli.policy_contract``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Tolerance of :func:`drive_differences`, relative and absolute (N m/rad, N m s/rad, rad): mjlab
#: writes its metadata with three decimals (``list_to_csv_str``, ``decimals=3``), so values that
#: agree to that rounding are the same drive.
DRIVE_TOLERANCE = 1e-3


@dataclass(frozen=True)
class DriveSpec:
    """PD gains and default pose of a policy's training, per joint in ``joint_names`` order.

    Attributes:
        kp: Position gains, N m/rad (> 0; 0 for a velocity drive); empty: not recorded (the
            robot's hold).
        kd: Damping gains, N m s/rad (>= 0); empty: not recorded.
        default_pose: The pose actions and joint observations are relative to, rad; empty: not
            recorded.
        kinds: Each joint's drive, ``"position"`` (a PD target, rad) or ``"velocity"`` (a speed
            target, rad/s: ``tau = kd (v_target - dq)``, kp 0, a wheel); the action maps to the
            drive's unit. Empty: every joint a position drive (the robot's own kinds hold).
    """

    kp: tuple[float, ...] = ()
    kd: tuple[float, ...] = ()
    default_pose: tuple[float, ...] = ()
    kinds: tuple[str, ...] = ()

    @property
    def empty(self) -> bool:
        return not (self.kp or self.kd or self.default_pose or self.kinds)

    def velocity(self, n: int) -> tuple[bool, ...]:
        """Per joint of ``n``: a velocity drive."""
        return tuple(k == "velocity" for k in self.kinds) if self.kinds else (False,) * n

    def problems(self, n: int) -> list[str]:
        """What is invalid for ``n`` joints (empty: valid): lengths, finiteness, signs."""
        out = []
        for name, values, low in (("kp", self.kp, 0.0), ("kd", self.kd, 0.0)):
            if values and len(values) != n:
                out.append(f"drive.{name}: {len(values)} entries, expected one per joint ({n})")
            elif values and not all(np.isfinite(v) and v >= low for v in values):
                out.append(f"drive.{name}: must be finite and >= 0, got {list(values)}")
        if self.kinds and (len(self.kinds) != n or set(self.kinds) - {"position", "velocity"}):
            out.append(
                f"drive.kinds: expected {n} entries of 'position' or 'velocity', got "
                f"{list(self.kinds)}"
            )
        elif self.kp and len(self.kp) == n:
            velocity = self.velocity(n)
            if not all(v == 0 if w else v > 0 for v, w in zip(self.kp, velocity, strict=True)):
                out.append(
                    f"drive.kp: must be positive (0 for a velocity drive), got {list(self.kp)}"
                )
        if self.default_pose and len(self.default_pose) != n:
            out.append(
                f"drive.default_pose: {len(self.default_pose)} entries, expected one per joint "
                f"({n})"
            )
        elif self.default_pose and not all(np.isfinite(v) for v in self.default_pose):
            out.append(f"drive.default_pose: must be finite, got {list(self.default_pose)}")
        return out


def drive_differences(drive: DriveSpec | None, robot) -> dict[str, str]:
    """Where a policy's drive differs from a robot's ``robot.toml``, one line per quantity.

    Args:
        drive: The policy's :class:`DriveSpec` (None or empty: no differences), in the robot's
            joint order.
        robot: The :class:`robots.Robot` (``config.joints[i].kp``/``kd``, ``home``).

    Returns:
        ``{"kp" | "kd" | "default_pose" | "kinds": line}`` for the quantities that differ, a line such as
        ``"kp (N m/rad): policy [25.0 x 12], robot.toml [20.0 x 12]"``; values within
        ``DRIVE_TOLERANCE`` agree.
    """
    if drive is None or drive.empty:
        return {}
    if drive.kinds:
        theirs = ["velocity" if v else "position" for v in robot.velocity_driven]
        if list(drive.kinds) != theirs:
            out_kinds = f"drive kinds: policy {list(drive.kinds)}, robot.toml {theirs}"
        else:
            out_kinds = None
    else:
        out_kinds = None
    robot_values = {
        "kp": np.array([j.kp for j in robot.config.joints]),
        "kd": np.array([j.kd for j in robot.config.joints]),
        "default_pose": np.asarray(robot.home, dtype=float),
    }
    labels = {
        "kp": "kp (N m/rad)",
        "kd": "kd (N m s/rad)",
        "default_pose": "default pose (rad; robot.toml control.home)",
    }
    out = {}
    for key, theirs in robot_values.items():
        ours = np.asarray(getattr(drive, key), dtype=float)
        if ours.size and not np.allclose(ours, theirs, rtol=DRIVE_TOLERANCE, atol=DRIVE_TOLERANCE):
            out[key] = f"{labels[key]}: policy {_values(ours)}, robot.toml {_values(theirs)}"
    if out_kinds:
        out["kinds"] = out_kinds
    return out


def _values(v: np.ndarray) -> str:
    """``[25.0 x 12]`` for equal entries, else the list rounded to 4 decimals."""
    if v.size and np.all(v == v[0]):
        return f"[{round(float(v[0]), 4)} x {v.size}]"
    return "[" + ", ".join(f"{round(float(x), 4)}" for x in v) + "]"


def drive_robot(robot, spec):
    """``(robot to run, differences)`` of a policy's ``spec`` (a PolicySpec): ``robot`` itself
    when the spec's drive agrees with robot.toml (or records none), else the robot with the
    policy's kp, kd and default pose as its home (:func:`sim2real.robots.drive.with_drive`);
    ``differences`` is :func:`drive_differences`' dict.

    Raises:
        RobotSpecError: the policy's drive does not fit the robot (a default pose outside the
            joint limits).
    """
    differences = drive_differences(spec.drive, robot)
    if not differences:
        return robot, {}
    from sim2real.robots.drive import with_drive

    d = spec.drive
    kinds = d.kinds if "kinds" in differences else None
    return with_drive(robot, kp=d.kp, kd=d.kd, home=d.default_pose, kinds=kinds), differences
