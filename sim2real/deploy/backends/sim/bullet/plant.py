"""The plant on a second physics engine: pybullet steps the robot, everything else is the MuJoCo
plant's.

:class:`BulletBackend` is a :class:`~sim2real.deploy.backends.sim.plant.SimBackend` whose physics runs in
pybullet (sequential-impulse rigid contacts, a different solver and contact model from MuJoCo's
soft convex one). Each env's world is built from that env's compiled MuJoCo model
(:mod:`.build`), so the soak's randomized dynamics, floor friction, payloads and joint-friction
drift reach it; the drives are MuJoCo's actuator law evaluated at every physics step
(:mod:`.drive_law`) and applied as joint torques. The sensor models, the motor thermal model,
the torque derating, the anti-windup, fault hooks, checkpoints and ground truth are the MuJoCo
plant's own, on a MuJoCo *mirror*: after every control period each env's ``MjData`` takes
pybullet's state (joint and base position and velocity, the last physics step's acceleration)
and MuJoCo computes kinematics and the IMU from it; the feet's touch readings are pybullet's
contact normal forces. The runtime, monitors and reports cannot tell the engines apart.

What pybullet does not model the way MuJoCo does: armature (joint-space torques on an arm,
geared rotor links on a legged robot, see :mod:`.build`), soft contacts (bullet's are rigid,
with error reduction), friction combination.
A checkpoint restores the state from the mirror (positions, velocities, drive integrators):
pybullet's contact warm start is not kept, so a resumed session is close to, not bit-identical
with, an uninterrupted one.

Errors: :class:`~sim2real.deploy.backends.sim.plant.SimulationDivergedError` when pybullet's state
turns non-finite or huge; :class:`.convert.UnsupportedModelError` for a model it cannot build.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import pybullet as pb

from sim2real.deploy.backends.sim.bullet.build import ROTOR_GEAR_RATIO, BulletWorld, build_world
from sim2real.deploy.backends.sim.bullet.convert import quat_to_mat, wxyz, xyzw
from sim2real.deploy.backends.sim.bullet.drive_law import DriveLaw
from sim2real.deploy.backends.sim.legged_sensors import sensor_address
from sim2real.deploy.backends.sim.plant import SimBackend, SimulationDivergedError
from sim2real.robots import Robot

#: rad/s, the speed below which an arm's dry joint friction (``dof_frictionloss``) falls off
#: linearly to zero (a regularized Coulomb model; MuJoCo's own frictionloss is a soft constraint
#: that also creeps): small against the joints' working speeds, large enough for the explicit
#: viscous slope ``frictionloss / DRY_FRICTION_SPEED`` to stay stable with the armature.
DRY_FRICTION_SPEED = 0.01

#: A state component beyond this magnitude is a divergence (MuJoCo's own bound, ``mjMAXVAL``).
MAX_STATE = 1e10


def _root_body(m: mujoco.MjModel, robot: Robot) -> int:
    """The robot's root body: the floating base, or the world's child holding its joints."""
    if m.njnt > 0 and int(m.jnt_type[0]) == mujoco.mjtJoint.mjJNT_FREE:  # a floating base
        return int(m.body(robot.base_body).id)
    b = int(m.jnt_bodyid[0])
    while m.body_parentid[b] != 0:
        b = int(m.body_parentid[b])
    return b


class BulletBackend(SimBackend):
    """The plant with pybullet physics (module docstring); arguments as :class:`SimBackend`.

    Raises:
        UnsupportedModelError: a model pybullet cannot build (named part).
        ValueError: as :class:`SimBackend`.
    """

    engine = "pybullet"

    def __init__(
        self,
        robot: Robot,
        mode: str | None = None,
        envs: int = 1,
        seed: int = 0,
        models: Sequence[mujoco.MjModel] | None = None,
        max_latency_ticks: int = 32,
    ):
        self._worlds: list[BulletWorld | None] = [None] * max(envs, 1)
        self._laws: list[DriveLaw | None] = [None] * max(envs, 1)
        self._friction: list[np.ndarray | None] = [None] * max(envs, 1)
        self._forces: list[dict[int, np.ndarray]] = [{} for _ in range(max(envs, 1))]
        super().__init__(robot, mode, envs, seed, models, max_latency_ticks)
        m = self.models[0]
        touch = mujoco.mjtSensor.mjSENS_TOUCH
        self._touch = [sensor_address(m, touch, s) for s in robot.foot_site_ids]
        self._foot_links = [
            int(self._worlds[0].link_of_body[m.site_bodyid[s]]) for s in robot.foot_site_ids
        ]
        self._ctrl = np.zeros(self._nu)
        self._dq_before = np.zeros(self.n_joints)
        self._base_before = np.zeros(6)
        self._base = np.zeros(13)  # a base state read from pybullet (_base_state)
        self._bias = np.zeros(self.models[0].nv)
        self._force = np.zeros(self.models[0].nv)
        self._accel = np.zeros((1, self.models[0].nv))
        self.reset()  # the mirror's contacts replaced by pybullet's before the first reading

    # ------------------------------------------------------------------ building
    def _bind(self, e: int) -> None:
        super()._bind(e)
        m = self.models[e]
        old = self._worlds[e]
        if old is not None:
            pb.disconnect(old.client)
        root = _root_body(m, self.robot)
        self._worlds[e] = build_world(m, root, self.n_joints, self.free_base)
        self._laws[e] = DriveLaw(m, self._jnt_offset, self._qvel_offset, self.n_joints)
        self._friction[e] = None  # set before the next physics step
        self._sync_forces(e)

    def close(self) -> None:
        """Disconnect every env's pybullet client (the backend cannot step afterwards)."""
        for e, w in enumerate(self._worlds):
            if w is not None:
                pb.disconnect(w.client)
                self._worlds[e] = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown: pybullet may be gone already
            pass

    # ------------------------------------------------------------------ state transfer
    def _push_state(self, e: int) -> None:
        """Put env ``e``'s pybullet robot at its mirror's state (positions, velocities)."""
        w, d = self._worlds[e], self.datas[e]
        c, body = w.client, w.body
        q, dq = d.qpos[self._qpos_offset :], d.qvel[self._qvel_offset :]
        for i, j in enumerate(w.joint_index):
            pb.resetJointState(body, j, float(q[i]), float(dq[i]), physicsClientId=c)
            if w.rotor_index and w.rotor_index[i] >= 0:  # its rotor at the geared speed
                pb.resetJointState(
                    body,
                    w.rotor_index[i],
                    0.0,
                    -ROTOR_GEAR_RATIO * float(dq[i]),
                    physicsClientId=c,
                )
        if w.floating:
            self._push_base(e)

    def _push_base(self, e: int) -> None:
        w, d = self._worlds[e], self.datas[e]
        rot = quat_to_mat(d.qpos[3:7])
        arm = rot @ w.com_offset
        com = d.qpos[:3] + arm
        orientation = np.empty(4)
        mujoco.mju_mulQuat(orientation, d.qpos[3:7], w.com_quat)
        omega = rot @ d.qvel[3:6]
        velocity = d.qvel[:3] + np.cross(omega, arm)
        pb.resetBasePositionAndOrientation(
            w.body, com.tolist(), xyzw(orientation), physicsClientId=w.client
        )
        pb.resetBaseVelocity(w.body, velocity.tolist(), omega.tolist(), physicsClientId=w.client)

    def _base_state(self, w: BulletWorld, out: np.ndarray) -> None:
        """The base's MuJoCo free-joint state from pybullet into ``out`` (13,): position, quat
        (w, x, y, z), linear velocity of the body origin (world), angular velocity (body)."""
        com, orientation = pb.getBasePositionAndOrientation(w.body, physicsClientId=w.client)
        velocity, omega = pb.getBaseVelocity(w.body, physicsClientId=w.client)
        inertial = wxyz(orientation)
        quat = np.empty(4)
        conj = np.array([w.com_quat[0], -w.com_quat[1], -w.com_quat[2], -w.com_quat[3]])
        mujoco.mju_mulQuat(quat, inertial, conj)
        rot = quat_to_mat(quat)
        arm = rot @ w.com_offset
        omega = np.asarray(omega)
        out[:3] = np.asarray(com) - arm
        out[3:7] = quat
        out[7:10] = np.asarray(velocity) - np.cross(omega, arm)
        out[10:13] = rot.T @ omega

    # ------------------------------------------------------------------ the three calls
    def reset(self, q: np.ndarray | None = None, envs: np.ndarray | None = None) -> None:
        """As :meth:`SimBackend.reset`; pybullet's robots are put at the mirror's pose."""
        if not hasattr(self, "_ctrl"):  # SimBackend.__init__'s reset: the worlds are not ready
            return
        super().reset(q, envs)
        which = np.ones(self.envs, dtype=bool) if envs is None else np.asarray(envs, dtype=bool)
        for e in np.flatnonzero(which):
            self._sync_forces(e)  # MuJoCo's reset cleared xfrc_applied
            self._push_state(e)

    def advance(self) -> None:
        """One control period: ``decimation`` pybullet steps per env with the drives' torques,
        then the mirror, the thermal model and the sensors (as :meth:`SimBackend.advance`).

        Raises:
            SimulationDivergedError: pybullet's state of an env turned non-finite or huge.
        """
        command, torque, qpos = self._command, self._torque, self._qpos
        self.drives.derate(self.thermal.winding_temperature)
        if self.actuators.active:
            self.actuators.start_period(self.tick, command, self.thermal.winding_temperature)
        reps = self._nu // self.n_joints
        for e, (m, d, _ctrl, q, force, _warnings) in enumerate(self._views):
            ctrl = self._ctrl
            for r in range(reps):
                ctrl[r * self.n_joints : (r + 1) * self.n_joints] = command[e]
            d.ctrl[:] = ctrl
            self._step_env(e, m, d, ctrl)
            torque[e] = force
            qpos[e] = q
        if self.mode == "velocity":
            self.drives.anti_windup(qpos)
        self.tick += 1
        self.thermal.step(self._torque, self.control_period)
        self.sample_sensors()

    def _step_env(self, e: int, m: mujoco.MjModel, d: mujoco.MjData, ctrl: np.ndarray) -> None:
        w, law = self._worlds[e], self._laws[e]
        c, body, idx = w.client, w.body, w.joint_index
        dofs = slice(self._qvel_offset, self._qvel_offset + self.n_joints)
        # dry friction: a zero-velocity motor's torque, or with the armature's joint-space
        # torques (a constraint would act without the rotors) a regularized Coulomb torque
        armature = not w.floating and bool(m.dof_armature.any())
        friction = m.dof_frictionloss[dofs]
        motor = np.zeros_like(friction) if armature else friction
        if self._friction[e] is None or not np.array_equal(self._friction[e], motor):
            self._friction[e] = motor.copy()
            pb.setJointMotorControlArray(
                body,
                idx,
                pb.VELOCITY_CONTROL,
                targetVelocities=[0.0] * len(idx),
                forces=motor.tolist(),
                physicsClientId=c,
            )
        dt, nstep = float(m.opt.timestep), self.decimation
        act, tau = d.act, d.qfrc_actuator[dofs]
        state = self._base
        actuators = self.actuators if self.actuators.active else None  # as the MuJoCo plant's
        grid = ctrl.reshape(-1, self.n_joints)  # (actuators per joint, n) view of ctrl
        for s in range(nstep):
            states = pb.getJointStates(body, idx, physicsClientId=c)
            q = np.fromiter((x[0] for x in states), float, len(idx))
            dq = np.fromiter((x[1] for x in states), float, len(idx))
            if actuators is not None:  # delayed commands; the law clips to jnt_actfrcrange
                actuators.before_step(e, s, grid, dq, self.effort_limit[e], self._actfrc[e])
            tau[:] = law.torque(ctrl, act, q, dq, dt)
            applied = tau + law.passive(dq)
            if armature:
                applied -= friction * np.clip(dq / DRY_FRICTION_SPEED, -1.0, 1.0)
                applied = self._armature_torque(e, m, d, applied, q, dq)
            pb.setJointMotorControlArray(
                body, idx, pb.TORQUE_CONTROL, forces=applied.tolist(), physicsClientId=c
            )
            if self._forces[e]:
                self._apply_forces(w, self._forces[e])
            if s == 0:  # the period's mean acceleration (the IMU's anti-aliasing, see _pull)
                self._dq_before[:] = dq
                if w.floating:
                    self._base_state(w, state)
                    self._base_before[:] = state[7:]
            pb.stepSimulation(physicsClientId=c)
        self._pull(e, m, d, dt * nstep)

    def _armature_torque(
        self,
        e: int,
        m: mujoco.MjModel,
        d: mujoco.MjData,
        tau: np.ndarray,
        q: np.ndarray,
        dq: np.ndarray,
    ) -> np.ndarray:
        """The joint torque (N m, (n,)) under which pybullet's rigid-body dynamics ``M ddq =
        tau' - h`` accelerate a fixed-base arm as its drives with armature ``A`` would,
        ``(M + A) ddq = tau - h + J^T f``: ``tau' = tau - A (M + A)^-1 (tau - h + J^T f)``, with
        ``f`` the applied external forces (a cable, a push). ``M + A``, ``h`` (gravity, Coriolis)
        and ``J^T f`` come from MuJoCo on the env's mirror at ``q``, ``dq`` (pybullet's own
        ``calculateInverseDynamics`` disagreed with MuJoCo's gravity torques on the SO-101 while
        its mass matrix agreed; not used). Exact without constraints;
        a constraint force (a limit, a self-collision) accelerates the links without the
        rotors."""
        d.qpos[:] = q
        d.qvel[:] = dq
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_crb(m, d)  # M with the armature
        mujoco.mj_factorM(m, d)
        mujoco.mj_comVel(m, d)
        bias = self._bias
        mujoco.mj_rne(m, d, 0, bias)
        force = self._force  # the generalized force of the applied external forces
        force[:] = tau - bias
        if self._forces[e]:  # J^T f of each applied force, at its body's centre of mass
            for b in np.flatnonzero(np.any(d.xfrc_applied, axis=1)):
                xfrc = d.xfrc_applied[b]
                mujoco.mj_applyFT(m, d, xfrc[:3], xfrc[3:], d.xipos[b], int(b), force)
        accel = self._accel
        mujoco.mj_solveM(m, d, accel, force[None, :])
        return tau - m.dof_armature * accel[0]

    def _apply_forces(self, w: BulletWorld, forces: dict[int, np.ndarray]) -> None:
        """The external forces of an env (applied at each body's centre of mass; pybullet clears
        them after every step)."""
        for link, f in forces.items():
            if link < 0:
                at = pb.getBasePositionAndOrientation(w.body, physicsClientId=w.client)[0]
            else:
                at = pb.getLinkState(w.body, link, physicsClientId=w.client)[0]
            pb.applyExternalForce(
                w.body, link, f.tolist(), at, pb.WORLD_FRAME, physicsClientId=w.client
            )

    def _pull(self, e: int, m: mujoco.MjModel, d: mujoco.MjData, period: float) -> None:
        """Env ``e``'s mirror takes pybullet's state; MuJoCo computes kinematics and sensors.

        The acceleration the accelerometer sees is the mean over the control period
        (``period`` s): bullet's rigid contacts resolve as velocity jumps, so one step's
        difference is an impulse, not what an IMU behind its anti-aliasing filter reports."""
        w = self._worlds[e]
        off, voff = self._qpos_offset, self._qvel_offset
        states = pb.getJointStates(w.body, w.joint_index, physicsClientId=w.client)
        d.qpos[off:] = [x[0] for x in states]
        d.qvel[voff:] = [x[1] for x in states]
        d.qacc[voff:] = (d.qvel[voff:] - self._dq_before) / period
        if w.floating:
            state = self._base
            self._base_state(w, state)
            d.qpos[:7] = state[:7]
            d.qvel[:6] = state[7:]
            d.qacc[:6] = (state[7:] - self._base_before) / period
        if not (np.all(np.abs(d.qpos) < MAX_STATE) and np.all(np.abs(d.qvel) < MAX_STATE)):
            raise SimulationDivergedError(
                f"env {e}: pybullet diverged at t={self.time:.4f} s "
                f"(qpos={np.array2string(d.qpos, precision=3)})"
            )
        d.time += period
        mujoco.mj_fwdPosition(m, d)  # these four leave the qacc set above
        mujoco.mj_sensorPos(m, d)
        mujoco.mj_fwdVelocity(m, d)
        mujoco.mj_sensorVel(m, d)
        mujoco.mj_rnePostConstraint(m, d)  # cacc from this qacc (mj_sensorAcc may skip it)
        mujoco.mj_sensorAcc(m, d)
        for adr, link in zip(self._touch, self._foot_links, strict=True):
            points = pb.getContactPoints(bodyA=w.body, linkIndexA=link, physicsClientId=w.client)
            d.sensordata[adr] = sum(p[9] for p in points)

    # ------------------------------------------------------------------ hooks
    def set_base_velocity(self, env: int, velocity_xy: np.ndarray) -> None:
        """As :meth:`SimBackend.set_base_velocity`, in pybullet too."""
        super().set_base_velocity(env, velocity_xy)
        self._push_base(env)

    def push_base(self, env: int, twist: np.ndarray, add: bool = False) -> None:
        """As :meth:`SimBackend.push_base`, in pybullet too."""
        super().push_base(env, twist, add)
        self._push_base(env)

    def set_base_wrench(self, env: int, wrench: np.ndarray) -> None:
        """As :meth:`SimBackend.set_base_wrench`: its force applied at the base's centre of mass
        at every pybullet step until changed (its torque is the MuJoCo plant's only: pybullet's
        robots take forces, :meth:`_sync_forces`)."""
        super().set_base_wrench(env, wrench)
        self._sync_forces(env)

    def set_push_wrench(self, env: int, wrench: np.ndarray) -> np.ndarray:
        """As :meth:`SimBackend.set_push_wrench`: each body's force applied at its centre of mass
        at every pybullet step until changed (the torques are the MuJoCo plant's only)."""
        row = super().set_push_wrench(env, wrench)
        self._sync_forces(env)
        return row

    def set_external_force(self, env: int, force: np.ndarray, body: str | None = None) -> None:
        """As :meth:`SimBackend.set_external_force`: applied at the body's centre of mass at
        every pybullet step until changed."""
        super().set_external_force(env, force, body)
        self._sync_forces(env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """As :meth:`SimBackend.load_state_dict`; pybullet's robots take the loaded state."""
        super().load_state_dict(state, env)
        for e in range(self.envs) if env is None else [env]:
            self._push_state(e)
            self._sync_forces(e)

    def _sync_forces(self, e: int) -> None:
        """Env ``e``'s forces for pybullet (link -> (3,) N, world frame) from its mirror's
        ``xfrc_applied``, which holds them (set, reset and checkpointed by the MuJoCo plant)."""
        xfrc = self.datas[e].xfrc_applied
        link_of_body = self._worlds[e].link_of_body
        self._forces[e] = {
            int(link_of_body[b]): xfrc[b, :3].copy()
            for b in np.flatnonzero(np.any(xfrc[:, :3], axis=1))
        }

    def check_divergence(self, env: int) -> None:
        """Raise :class:`SimulationDivergedError` if env ``env``'s state is not finite."""
        d = self.datas[env]
        if not (np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()):
            raise SimulationDivergedError(f"env {env}: pybullet's state is not finite")
