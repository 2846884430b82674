"""The drives of a compiled MuJoCo model, evaluated outside MuJoCo: the torque each joint's
actuators apply, as MuJoCo's actuator model defines it, for a plant that steps another engine.

For actuator ``k`` on joint ``j`` (transmission ``mjTRN_JOINT``, gear ``g``; MuJoCo's "Actuation
model", mujoco.readthedocs.io, Computation chapter)::

    u   = act_k (integrator dynamics) or clip(ctrl_k, ctrlrange_k)
    f_k = gain_k u + bias0_k + bias1_k (g q_j) + bias2_k (g dq_j)    (clipped to forcerange_k)
    tau_j = clip(sum_k g f_k, actfrcrange_j)              (and passive: - damping_j dq_j)
    act_k <- clip(act_k + dt ctrl_k, actrange_k)                      (after the force)

which covers the drives of :meth:`robots.Robot.mjspec`: position servos (``gain kp``, ``bias
-kp q - kv dq``), the velocity loop's integral (``intvelocity``) and proportional (``velocity``)
terms, and direct motors. The model's arrays are read when the law is built, except the joint
torque limits (``jnt_actfrcrange``, which the plant derates from the winding temperature at run
time) and the damping, read at every :meth:`DriveLaw.torque`.

Errors: :class:`~sim2real.deploy.backends.sim.bullet.convert.UnsupportedModelError` for an actuator with
another transmission, gain or bias type.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.deploy.backends.sim.bullet.convert import UnsupportedModelError


class DriveLaw:
    """MuJoCo's actuator forces of model ``m`` on its ``n`` robot joints (module docstring).

    Args:
        m: The compiled model (its actuators all on joints).
        jnt_offset: MuJoCo joint id of the robot's first joint (1 after a free joint).
        dof_offset: Its dof index (6 after a free joint).
        n: Number of robot joints.
    """

    def __init__(self, m: mujoco.MjModel, jnt_offset: int, dof_offset: int, n: int):
        self.m, self.n = m, n
        self.jnt = slice(jnt_offset, jnt_offset + n)
        self.dofs = slice(dof_offset, dof_offset + n)
        nu = m.nu
        dyn_ok = (int(mujoco.mjtDyn.mjDYN_NONE), int(mujoco.mjtDyn.mjDYN_INTEGRATOR))
        bias_ok = (int(mujoco.mjtBias.mjBIAS_NONE), int(mujoco.mjtBias.mjBIAS_AFFINE))
        bad = [
            m.actuator(k).name
            for k in range(nu)
            if int(m.actuator_trntype[k]) != int(mujoco.mjtTrn.mjTRN_JOINT)
            or int(m.actuator_gaintype[k]) != int(mujoco.mjtGain.mjGAIN_FIXED)
            or int(m.actuator_biastype[k]) not in bias_ok
            or int(m.actuator_dyntype[k]) not in dyn_ok
        ]
        if bad:
            raise UnsupportedModelError(
                f"actuators {bad}: expected joint transmission, fixed gain, affine or no bias, "
                "no or integrator dynamics"
            )
        self.joint = m.actuator_trnid[:, 0] - jnt_offset  # robot joint of each actuator
        if nu and (self.joint.min() < 0 or self.joint.max() >= n):
            raise UnsupportedModelError("an actuator drives a joint outside the robot's joints")
        self.gear = m.actuator_gear[:, 0].copy()
        self.gain = m.actuator_gainprm[:, 0].copy()
        biased = m.actuator_biastype == int(mujoco.mjtBias.mjBIAS_AFFINE)
        self.bias = m.actuator_biasprm[:, :3] * biased[:, None]
        self.integrator = m.actuator_dyntype == int(mujoco.mjtDyn.mjDYN_INTEGRATOR)
        self.act_index = m.actuator_actadr.copy()  # actuator -> its slot in MjData.act
        self.ctrl_lo = np.where(m.actuator_ctrllimited, m.actuator_ctrlrange[:, 0], -np.inf)
        self.ctrl_hi = np.where(m.actuator_ctrllimited, m.actuator_ctrlrange[:, 1], np.inf)
        self.force_lo = np.where(m.actuator_forcelimited, m.actuator_forcerange[:, 0], -np.inf)
        self.force_hi = np.where(m.actuator_forcelimited, m.actuator_forcerange[:, 1], np.inf)
        actlimited = m.actuator_actlimited.astype(bool)
        self.act_lo = np.where(actlimited, m.actuator_actrange[:, 0], -np.inf)[self.integrator]
        self.act_hi = np.where(actlimited, m.actuator_actrange[:, 1], np.inf)[self.integrator]
        self._limited = m.jnt_actfrclimited[self.jnt].astype(bool)
        self._u = np.empty(nu)
        self._f = np.empty(nu)
        self._tau = np.empty(n)

    def torque(
        self, ctrl: np.ndarray, act: np.ndarray, q: np.ndarray, dq: np.ndarray, dt: float
    ) -> np.ndarray:
        """The joints' torque (N m, (n,); reused buffer) for actuator inputs ``ctrl`` ((nu,)),
        integrator states ``act`` ((na,), advanced by ``dt`` s in place), joint angles ``q``
        and velocities ``dq`` ((n,))."""
        m, u, f, tau = self.m, self._u, self._f, self._tau
        np.clip(ctrl, self.ctrl_lo, self.ctrl_hi, out=u)
        integ = self.integrator
        if act.size:
            u[integ] = act[self.act_index[integ]]
        length = self.gear * q[self.joint]
        velocity = self.gear * dq[self.joint]
        np.multiply(self.gain, u, out=f)
        f += self.bias[:, 0] + self.bias[:, 1] * length + self.bias[:, 2] * velocity
        np.clip(f, self.force_lo, self.force_hi, out=f)
        tau.fill(0.0)
        np.add.at(tau, self.joint, self.gear * f)
        limit = m.jnt_actfrcrange[self.jnt]
        np.clip(
            tau,
            np.where(self._limited, limit[:, 0], -np.inf),
            np.where(self._limited, limit[:, 1], np.inf),
            out=tau,
        )
        if act.size:  # MuJoCo's integrator dynamics, after the force (act_dot = ctrl)
            act += dt * np.clip(ctrl, self.ctrl_lo, self.ctrl_hi)[integ]
            np.clip(act, self.act_lo, self.act_hi, out=act)
        return tau

    def passive(self, dq: np.ndarray) -> np.ndarray:
        """The joints' viscous damping torque (N m, (n,)) at velocities ``dq`` (rad/s): passive,
        apart from the drives' actuator torque."""
        return -self.m.dof_damping[self.dofs] * dq
