"""The motor commands of one LowCmd (:func:`fill_motor_commands`): what
:class:`~sim2real.deploy.backends.unitree.backend.UnitreeBackend` encodes in each joint's slot of
``motor_cmd`` for each driver's law ``tau = tau_ff + kp (q_des - q) + kd (dq_des - dq)``.

A velocity-driven joint (a wheel, robot.toml or the policy's ``drive = "velocity"``) takes its
speed target in ``dq_des`` with ``q_des`` 0 and ``kp`` 0, so that its law is ``kd (dq_des - dq)``
(rl_sar's Go2-W: wheels ``kp`` 0, ``kd`` 0.5); while the bring-up and the hold send position
targets it takes speed 0 (its angle is any), and damping brakes it as every joint.
"""

from __future__ import annotations

import numpy as np

#: What a LowCmd asks of the drivers.
KINDS = ("damping", "hold", "position", "torque")


def fill_motor_commands(
    mc: np.ndarray,
    slots: np.ndarray,
    wheels: np.ndarray,
    motor_mode: int,
    kind: str,
    target: np.ndarray,
    kp,
    kd,
) -> None:
    """Write the joints' slots of ``mc`` (a LowCmd's ``motor_cmd`` records).

    Args:
        mc: The ``motor_cmd`` record array (written: ``mode``, ``q``, ``dq``, ``tau``, ``kp``,
            ``kd``). slots: (n,) int, the motor slot of each joint.
        wheels: (k,) int, the joint indices of the velocity-driven joints.
        motor_mode: robot.toml's ``[unitree] motor_mode``.
        kind: ``"damping"`` (kp 0 and ``kd``), ``"hold"`` (``target`` a pose, rad, with ``kp``,
            ``kd``: the bring-up's and the hold's; wheels at speed 0), ``"position"`` (the
            runtime's ``target``: rad, a wheel's rad/s) or ``"torque"`` (``target`` N m, kp = kd
            = 0).
        target: (n,) the command; kp, kd: (n,) or scalars, N m/rad and N m s/rad.
    """
    s = slots
    mc["mode"][s] = motor_mode
    mc["dq"][s] = 0.0
    if kind == "torque":
        mc["q"][s], mc["tau"][s], mc["kp"][s], mc["kd"][s] = 0.0, target, 0.0, 0.0
        return
    if kind == "damping":
        mc["q"][s], mc["tau"][s], mc["kp"][s], mc["kd"][s] = 0.0, 0.0, 0.0, kd
        return
    mc["q"][s], mc["tau"][s], mc["kp"][s], mc["kd"][s] = target, 0.0, kp, kd
    if wheels.size:
        w = slots[wheels]
        mc["dq"][w] = target[wheels] if kind == "position" else 0.0
        mc["q"][w] = mc["kp"][w] = 0.0
