"""The motion envelope: no smoother step leaves the guard if the robot, braking from the state
that step puts it in, could touch itself or leave its workspace box.

The guard (:class:`sim2real.deploy.safety.guard.SafetyGuard`) checks the *target* of each tick. A target
far from the present pose (a position-mode policy may ask for any pose of the range, 500 times a
second) is reached along the smoother's jerk-limited path, and a collision-free target says
nothing about that path; nor can a moving arm stop at once when the next target turns out bad.
The envelope closes that gap the way speed-and-separation monitoring does (ISO/TS 15066): after
every smoother step it checks the whole motion the robot is committed to, and if that motion
could bring a listed collision pair within ``margin``, or the end effector within ``margin`` of
a face of the workspace box, the step is replaced by the smoother's brake
(:meth:`sim2real.deploy.smoothing.CommandSmoother.brake`).

The envelope certifies position-mode commands of fixed-base robots. Velocity mode has none yet: a
PI velocity drive runs ahead of its braking command and pulls the joint toward a setpoint the
runtime does not see, and every bound of that tried so far either let the adversarial policy out
of arm3's box or braked the shipped arm3 policy often enough to fail its soak
(``docs/measurements.md`` has the figures). Torque mode has no smoother trajectory to certify
(the guard's torque hold brakes instead), and a floating-base robot's leg targets are PD torques
in disguise.

How a motion is certified: :class:`MotionEnvelope`.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
from ruckig import (
    ControlInterface,
    InputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
    Trajectory,
)

from sim2real.deploy.safety import envelope_kernel as ek
from sim2real.deploy.safety.local_reach import LocalReach
from sim2real.deploy.safety.pair_grid import PairTables, pair_grids, table_bound
from sim2real.robots.chain_bounds import descends

#: m, default clearance kept between listed collision geometries and from the workspace box's
#: faces: our choice, a few times the joint estimate's error times a lever of about a metre, plus
#: the position servo's deviation from the box of its command path; capped at half the home
#: pose's own clearance (see ``MotionEnvelope``).
DEFAULT_MARGIN = 0.01
#: Smallest share of the full deceleration the envelope assumes of a derated drive (our choice: a
#: drive derated to its floor still holds the arm; its brake is taken as 20 times longer).
MIN_HEADROOM = 0.05
#: m, distances within this of each other are equal (coal's round-off between configurations
#: that leave a pair's relative pose unchanged).
DISTANCE_TOLERANCE = 1e-9
#: Segments of the brake the path certification cuts by time (our choice: a few Pinocchio
#: calls, only where the whole box is uncertain).
PATH_SEGMENTS = 4
#: m, how much a robot within the margin must gain back per step in torque mode (our choice,
#: about the estimate's noise times a lever of a metre): the start of a torque step is the noisy
#: estimate, and "no closer than now" then let a ur5 pressed down by its policy random-walk
#: through its box's floor; a servo's command path has no such noise.
TORQUE_ESCAPE = 1e-3


def axis_levers(robot, ee_lever: np.ndarray) -> np.ndarray:
    """(3, n) m/rad, bound of the end effector's displacement along world x, y, z per radian of
    each joint: ``ee_lever`` (n,), times ``|e_k x a_i|`` where joint ``i``'s axis ``a_i`` keeps
    its world direction in every configuration (every joint above it turns about a parallel
    axis; a rotation about ``a_i`` moves points perpendicular to it), else times 1."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    ids = [m.joint(name).id for name in robot.joint_names]
    out = np.tile(np.asarray(ee_lever, dtype=float), (3, 1))
    for i, j in enumerate(ids):
        axis = d.xaxis[j] / np.linalg.norm(d.xaxis[j])
        body, invariant = m.jnt_bodyid[j], m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
        for k in range(m.njnt):
            if k == j or not invariant or not descends(m, body, m.jnt_bodyid[k]):
                continue
            if np.linalg.norm(np.cross(d.xaxis[k], axis)) > 1e-9 * np.linalg.norm(d.xaxis[k]):
                invariant = False
        if invariant:
            out[:, i] *= np.linalg.norm(np.cross(np.eye(3), axis), axis=1)
    return out


class MotionEnvelope:
    """Certify each env's committed motion against self-collision and the workspace box.

    The committed motion lies, joint by joint, in a box: from the estimated position (a position
    servo lags its command), through the smoother's position before and after the step, to where the
    joint rests if the smoother brakes from its new state
    (:func:`sim2real.deploy.safety.envelope_kernel.brake_reach`; a thermally derated drive brakes with the
    torque it has left above the worst gravity load,
    :func:`sim2real.deploy.safety.envelope_kernel.brake_headroom`).

    One exact query at the box's centre certifies the whole box: a pair's distance (coal) changes by
    at most ``weights_p @ |dq|`` (:func:`sim2real.robots.chain_bounds.collision_pair_weights`), or by the
    local bound of the speeds of its points at the centre where that is smaller
    (:mod:`sim2real.deploy.safety.local_reach`), the end
    effector's margin along each axis by at most ``lever @ |dq|``
    (:func:`sim2real.robots.chain_bounds.end_effector_lever`; zero along an axis a joint's rotation never
    moves, :func:`axis_levers`) or by the local bound of the end effector's Jacobian at the centre
    (:meth:`MotionEnvelope._reach`). A pair moved by at most two joints also has a table of lower
    bounds over a grid of those joints (:mod:`sim2real.deploy.safety.pair_grid`): its distance stays above
    the least bound of the cells the box covers, which certifies boxes the chain bound does not
    where the distance hardly changes with a joint (the SO-101's base about its pan axis); the
    higher of the two bounds counts. The same bounds screen each box against the last query, so far
    from contact no query runs (the decision is the same with or without that cache). A box one
    query cannot certify over-covers the motion (its corners combine one joint's start with
    another's end): the step and Ruckig's own brake are then cut into :data:`PATH_SEGMENTS` by
    time, each joint monotonic within one, and each segment is certified. Workspace faces beyond
    the end effector's reach are never crossed and not checked.

    By induction the brake is always safe to take: the previous tick certified the motion that holds
    it. A robot already within the margin (pushed there, or started there) may only move so that no
    pair's distance and no workspace margin shrinks, checked at the step's end and at its brake's
    rest point; otherwise it brakes.

    Args:
        robot: The robot (limits, workspace box, collision pairs).
        envs: Batch size.
        geometry: ``(geom_model, geom_data)``, the guard's coal model
            (:func:`sim2real.deploy.safety.collision.collision_model`; a data of its own).
        pair_weights: (pairs, n) m/rad, :func:`sim2real.robots.chain_bounds.collision_pair_weights`.
        ee_lever: (n,) m/rad, :func:`sim2real.robots.chain_bounds.end_effector_lever`.
        gravity_bound: (n,) N m, each joint's worst gravity torque
            (:func:`sim2real.robots.chain_bounds.motion_bounds`).
        reach: m, :func:`sim2real.robots.chain_bounds.end_effector_reach` (faces beyond it are dropped).
        margin: m, clearance kept (``safety.clearance_margin`` of robot.toml); default
            :data:`DEFAULT_MARGIN`, capped at half of each pair's smallest distance with the
            joints that move it swept one at a time from home (:meth:`_sweep_clearance`) and
            at half the home pose's workspace margin.

    Attributes:
        unsafe: (2, envs) bool, rows collision and workspace: the envs the last :meth:`check`
            found unsafe.
        joints: (envs, n) bool, the joints of those envs to brake: the ones that move what
            could not be certified.
        queries: int, exact (Pinocchio) queries so far: a cost figure.
    """

    def __init__(
        self,
        robot,
        envs,
        geometry,
        pair_weights,
        ee_lever,
        gravity_bound,
        reach=np.inf,
        margin=None,
        drive=None,
        torque=None,
    ):
        self.robot, self.envs = robot, envs
        #: the velocity drives' model (:class:`sim2real.deploy.safety.drive.VelocityDrive`), or None for
        #: position servos, whose command path is the motion
        self.drive = drive
        #: torque mode's motion and brake (:class:`sim2real.deploy.safety.torque_drive.TorqueDrive`), or
        #: None: a smoother's trajectory is the motion
        self.torque = torque
        #: (envs,) bool: torque mode, the envs whose motion box left a soft joint limit or whose
        #: speed would pass the soft velocity limit; velocity mode, those whose drive would run
        #: past its velocity limit (:meth:`sim2real.deploy.safety.drive.VelocityDrive.motion`)
        self.beyond = np.zeros(envs, dtype=bool)
        self._drive_beyond = False  # whether the drive's kernel set beyond this tick
        #: m, what a robot within the margin must gain back per step (:data:`TORQUE_ESCAPE` in
        #: torque mode, else 0)
        self._escape = TORQUE_ESCAPE if torque is not None else 0.0
        n = robot.n_joints
        s = robot.config.safety
        self.model = robot.fixed_base_model
        self.data = self.model.createData()
        self.geom_model, self.geom_data = geometry
        self.pairs = len(pair_weights)
        self.has_workspace = s.workspace_min is not None
        #: the share by which each link may be longer or shorter than the MJCF's
        #: (``safety.link_length_tolerance``; 0: the description is exact)
        self.link_length_tolerance = float(s.link_length_tolerance or 0.0)
        tol = self.link_length_tolerance
        # the end effector's chain: Pinocchio's joints from the base to it, and their q indices
        frame = self.model.frames[robot.ee_frame_id]
        self._ee_chain = [j for j in self.model.supports[frame.parentJoint] if j > 0]
        if self.has_workspace:  # a face beyond the longest chain's reach can never be crossed
            reach = (1.0 + tol) * reach
            self.ws_min = np.where(np.array(s.workspace_min) <= -reach, -np.inf, s.workspace_min)
            self.ws_max = np.where(np.array(s.workspace_max) >= reach, np.inf, s.workspace_max)
        # (4, n): the smoother's acceleration and jerk limits, the worst gravity load's share of
        # each effort limit, MIN_HEADROOM
        self.limits = np.stack(
            [
                robot.acceleration_limit,
                robot.jerk_limit,
                np.asarray(gravity_bound) / robot.effort_limit,
                np.full(n, MIN_HEADROOM),
            ]
        )
        if torque is not None:  # the guard's computed-torque stop, not the smoother's brake
            self.limits[:2] = torque.brake_limits
        #: (pairs,) bool, the pairs the joints between their links cannot bring into contact
        #: (:func:`sim2real.deploy.safety.pair_grid.pairs_kept_apart`): left out of the certification (their
        #: distance reads as infinite), so a gripper's jaw closing next to its wrist brakes nothing
        self.apart = np.zeros(0, dtype=bool)
        #: the other pairs' lower-bound tables over the joints that move them
        #: (:class:`sim2real.deploy.safety.pair_grid.PairTables`), from the same grids
        self.tables = PairTables.empty(self.pairs)
        if self.pairs:
            self.apart, self.tables = pair_grids(robot, geometry, pair_weights)
        #: the pairs' local approach bounds (:class:`sim2real.deploy.safety.local_reach.LocalReach`)
        self.local = LocalReach(robot, geometry)
        self.queries = 0
        home = np.asarray(robot.home, dtype=float)
        if margin is None:  # the default, capped at half the clearance the geometry allows
            clear = self._sweep_clearance(home, np.asarray(pair_weights)) if self.pairs else []
            if self.has_workspace:
                clear.append(self.workspace_margin(home).min())
            margin = min([DEFAULT_MARGIN, *(0.5 * c for c in clear if c > 0.0)])
            self.queries = 0
        self.margin = float(margin)
        # rows: each pair's approach bound, then the end effector's levers along x, y, z (0
        # without a box)
        self.weights = np.zeros((self.pairs + 3, n))
        self.weights[: self.pairs] = pair_weights
        #: (n,) m/rad: how fast the end effector's error bound (:meth:`kinematic_error`) can
        #: change per radian of each joint, ``tolerance`` times the chain's length beyond it
        self._error_weight = tol * self._chain_beyond(home)
        if self.has_workspace:
            self.weights[self.pairs :] = axis_levers(robot, ee_lever) + self._error_weight
        #: (n, n) m/rad^2: min(lever_i, lever_j), bound of the end effector's second derivatives
        self._curvature = np.minimum.outer(np.asarray(ee_lever), np.asarray(ee_lever))
        # cache of the last exact query: its configuration (rows collision, workspace) and the
        # distances there (pairs, then the workspace margins along x, y, z); -inf: unknown, inf:
        # nothing to check
        self._cached_q = np.zeros((2, envs, n))
        self._clearance = np.full((envs, self.pairs + 3), -np.inf)
        if not self.has_workspace:
            self._clearance[:, self.pairs :] = np.inf
        if not self.pairs:
            self._clearance[:, : self.pairs] = np.inf
        # m/rad, the pairs' speeds at the cached collision query (LocalReach.speeds); the global
        # weights until the first
        self._speeds = np.tile(np.asarray(pair_weights, dtype=float).reshape(self.pairs, n),
                               (envs, 1, 1))  # fmt: skip
        # centre, half-width, the brake's rest point, the brake's headroom, its reversal
        self._box = np.zeros((5, envs, n))
        self._need = np.zeros((2, envs), dtype=bool)
        # the brake's path (_path_certified): Ruckig to rest, one env's joints at a time
        self._path_ruckig = Ruckig(n)
        self._path = Trajectory(n)
        self._path_inp = inp = InputParameter(n)
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.No
        inp.max_velocity = 2.0 * np.asarray(robot.velocity_limit)
        inp.max_jerk = self.limits[1]
        inp.target_velocity = inp.target_acceleration = np.zeros(n)
        self.unsafe = np.zeros((2, envs), dtype=bool)
        self.joints = np.zeros((envs, n), dtype=bool)
        self._dirty = False
        #: (envs, n) rad, how far a joint may stray from the certified path (0: a position servo)
        self._slack = np.zeros((envs, n))
        #: (envs, n) rad, signed: how far past the brake's rest a joint may run (a velocity
        #: drive's lead, :meth:`sim2real.deploy.safety.drive.VelocityDrive.motion`; 0: a position servo)
        self._lead = np.zeros((envs, n))
        # a velocity drive's path: the smoother's state with its equilibrium as the position
        self._drive_path = np.zeros((2, 3, envs, n))
        ek.warm_up()

    # ------------------------------------------------------------------ exact queries
    def _sweep_clearance(self, home: np.ndarray, pair_weights: np.ndarray) -> list[float]:
        """m, the smallest distance of each pair, at home and with each joint that moves it
        swept alone across its position range from home (65 poses): what the robot's own
        geometry allows (a gripper's jaw passes within millimetres of its wrist)."""
        at_home = self.distances(home)
        swept = np.full((self.robot.n_joints, self.pairs), np.inf)  # per joint, each pair's min
        for j in np.flatnonzero(np.asarray(pair_weights).any(axis=0)):
            for x in np.linspace(self.robot.position_lower[j], self.robot.position_upper[j], 65):
                pose = home.copy()
                pose[j] = x
                np.minimum(swept[j], self.distances(pose), out=swept[j])
        return [
            float(min(at_home[p], swept[np.flatnonzero(w), p].min(initial=np.inf)))
            for p, w in enumerate(pair_weights)
        ]

    def distances(self, q: np.ndarray) -> np.ndarray:
        """(pairs,) m, each listed pair's distance at ``q`` (n,) rad (coal; <= 0 in contact;
        ``inf`` for a pair kept apart, :attr:`apart`)."""
        self.queries += 1
        pin.computeDistances(self.model, self.data, self.geom_model, self.geom_data, q)
        d = np.array([r.min_distance for r in self.geom_data.distanceResults])
        d[self.apart] = np.inf
        return d

    def workspace_margin(self, q: np.ndarray) -> np.ndarray:
        """(3,) m, how far the end effector at ``q`` (n,) rad lies inside the workspace box along
        x, y, z (negative outside), for every chain within the link-length tolerance: the
        nominal margin less :meth:`kinematic_error`."""
        self.queries += 1
        pin.forwardKinematics(self.model, self.data, q)
        ee = pin.updateFramePlacement(self.model, self.data, self.robot.ee_frame_id).translation
        margin = np.minimum(ee - self.ws_min, self.ws_max - ee)
        if self.link_length_tolerance > 0.0:
            margin -= self.kinematic_error(ee)
        return margin

    def kinematic_error(self, ee: np.ndarray) -> np.ndarray:
        """(3,) m, bound of how far along x, y, z the true end effector lies from ``ee`` (3,) m,
        the model's at the configuration of the last forward kinematics, when each link is
        longer or shorter by up to :attr:`link_length_tolerance` of its length: that share of
        the sum of the absolute components of the chain's segments (joint to joint, the last
        to the end effector). A link scaled by ``s`` scales its segment (as the soak's link
        lengths do, :func:`sim2real.eval.world.dynamics.apply_dynamics`); the base's offset is exact."""
        return self.link_length_tolerance * np.abs(self._segments(ee)).sum(axis=0)

    def _segments(self, ee: np.ndarray) -> np.ndarray:
        """(k, 3) m, the end effector's chain at the last forward kinematics, joint to joint and
        the last to ``ee`` (3,) m."""
        points = [self.data.oMi[j].translation for j in self._ee_chain] + [ee]
        return np.diff(points, axis=0)

    def _chain_beyond(self, q: np.ndarray) -> np.ndarray:
        """(n,) m, for each joint of the end effector's chain the summed length of the chain's
        segments beyond it (0 for the other joints): a segment's length does not change with
        the pose, and a joint turns every segment beyond it."""
        pin.forwardKinematics(self.model, self.data, q)
        ee = pin.updateFramePlacement(self.model, self.data, self.robot.ee_frame_id).translation
        lengths = np.linalg.norm(self._segments(ee), axis=1)
        out = np.zeros(self.robot.n_joints)
        for k, j in enumerate(self._ee_chain):
            out[self.model.joints[j].idx_q] = lengths[k:].sum()
        return out

    # ------------------------------------------------------------------ the check
    def check(self, q, before, after, stopping, effort_scale, dq=None, command=None) -> bool:
        """Find the envs whose committed motion is not certified safe: :attr:`unsafe`.

        Args:
            q: (envs, n) rad, the estimated joint positions.
            before: (3, envs, n) the smoother's position, velocity and acceleration (rad, rad/s,
                rad/s^2) before its step (``CommandSmoother.before``).
            after: (3, envs, n) the same after it (``CommandSmoother.trajectory``).
            stopping: (envs,) bool, the envs braking to a stop already (not checked).
            effort_scale: (envs, n), the drives' thermal derating (the guard's).
            dq: (envs, n) rad/s, the estimated joint velocities; torque and velocity mode.
            command: (envs, n) N m, the step's torque; torque mode only (``before`` and
                ``after`` are then unused: the smoother has no trajectory).

        Returns:
            Whether any env is unsafe (:attr:`unsafe`, (2, envs) bool, rows collision and
            workspace, is written only then; it is all False otherwise).
        """
        if self._dirty:
            self.unsafe.fill(False)
            self.joints.fill(False)
            self.beyond.fill(False)
            self._dirty = False
        if self.torque is not None:
            before, after, slack = self.torque.motion(q, dq, command)
            np.copyto(self._slack, slack)
        elif self.drive is not None:
            before, after = self._drive_motion(q, dq, before, after, effort_scale, stopping)
        box, need = self._box, self._need
        uncertain = ek.envelope_screen(
            q, before, after, stopping, self.limits, effort_scale, self._cached_q,
            self._clearance, self.weights, self.margin, box, need, *self.tables.arrays(),
            self._speeds, self.local.order, self.local.nest, self._slack,
            self._lead,
        )  # fmt: skip
        if self.torque is not None:
            self.torque.beyond_limits(box, self.beyond)
        beyond = False  # a position servo has no drive model: beyond stays all False
        if self.torque is not None:
            self.beyond &= ~stopping
            beyond = bool(self.beyond.any())
        elif self.drive is not None:  # the drive's kernel left the stopping envs out
            beyond = self._drive_beyond
        if beyond:
            self.joints[self.beyond] = True  # every joint of those envs brakes
        self._dirty = beyond
        if uncertain:
            self._query(q, before, after, box, need)
            self._dirty |= bool(self.unsafe.any())
        return self._dirty

    def _query(self, q, before, after, box, need) -> None:
        """Certify with Pinocchio the envs the screen marked in ``need``; mark the others in
        :attr:`unsafe` and their joints in :attr:`joints`."""
        c, h = box[0], box[1]
        for e in np.flatnonzero(need[ek.COLLISION]):
            d = self._clearance[e, : self.pairs]
            d[:] = self.distances(c[e])
            self._speeds[e] = self.local.speeds(c[e])
            self._cached_q[ek.COLLISION, e] = c[e]
            if not self._certified(ek.COLLISION, c[e], h[e], d, self._speeds[e]):
                if not self._passes(ek.COLLISION, e, q, before, after):
                    self.unsafe[ek.COLLISION, e] = True
                    self._mark_joints(ek.COLLISION, e, c[e], h[e], d)
        for e in np.flatnonzero(need[ek.WORKSPACE]):
            inside = self._clearance[e, self.pairs :]
            inside[:] = self.workspace_margin(c[e])
            self._cached_q[ek.WORKSPACE, e] = c[e]
            if not self._certified(ek.WORKSPACE, c[e], h[e], inside):
                if not self._passes(ek.WORKSPACE, e, q, before, after):
                    self.unsafe[ek.WORKSPACE, e] = True
                    self._mark_joints(ek.WORKSPACE, e, c[e], h[e], inside)

    def _drive_motion(self, q, dq, before, after, effort_scale, stopping):
        """A velocity drive's motion (:mod:`sim2real.deploy.safety.drive`): the smoother's state before and
        after its step with the drives' equilibrium in place of the smoother's position (before:
        where the joints rest if the commands stop now; after: once the step's command has been
        integrated), and the drives' slack (:attr:`_slack`); :attr:`beyond` of the envs not
        ``stopping`` and whether any is set (``_drive_beyond``). Returns ``(before, after)``
        (3, envs, n) each."""
        path = self._drive_path
        np.copyto(path[0], before)
        np.copyto(path[1], after)
        self._drive_beyond = self.drive.motion(
            q, dq, after, effort_scale, self.limits, path[0, 0], path[1, 0], self._slack,
            self._lead, self.beyond, stopping,
        )  # fmt: skip
        return path[0], path[1]

    def commit(self, command: np.ndarray) -> None:
        """The tick's final ``command`` (envs, n), as written to the drives: a velocity drive's
        integrators take it (:meth:`sim2real.deploy.safety.drive.VelocityDrive.integrate`), torque mode
        its acceleration (:meth:`sim2real.deploy.safety.torque_drive.TorqueDrive.commit`); nothing for a
        position servo."""
        if self.drive is not None:
            self.drive.integrate(command)
        elif self.torque is not None:
            self.torque.commit(command)

    def _mark_joints(self, kind: int, e: int, centre, half, value) -> None:
        """Mark in :attr:`joints` the joints of env ``e`` that move a quantity of ``kind`` the
        box could not certify (a pair's weight, or the end effector's lever, above zero): only
        they are braked; the others leave that quantity as it is."""
        rows = slice(None, self.pairs) if kind == ek.COLLISION else slice(self.pairs, None)
        uncertain = self._lower_bounds(kind, centre, half, value) <= self.margin
        self.joints[e] |= (self.weights[rows][uncertain] > 0.0).any(axis=0)

    def _passes(self, kind: int, e: int, q, before, after) -> bool:
        """Env ``e``'s motion, which its whole box could not certify: certified segment by
        segment (:meth:`_path_certified`), or a robot already within the margin moving back out
        (:meth:`_escapes_contact`, :meth:`_escapes_box`)."""
        start, end, box = before[0, e], after[0, e], self._box[:, e]
        rest, share, reversal = box[2], box[3], box[4]
        if self._path_certified(
            kind, q[e], start, end, after[1, e], after[2, e], share, reversal, self._slack[e]
        ):
            return True
        if kind == ek.COLLISION:
            return self._escapes_contact(start, end, rest)
        return self._escapes_box(start, end, rest)

    def _reach(self, kind: int, centre, half, speeds=None) -> np.ndarray:
        """How far each quantity of ``kind`` can shrink in the box ``centre +- half`` (n,) rad:
        for the pairs the local bound (:func:`sim2real.deploy.safety.envelope_kernel.pairs_reach`; ``speeds``
        (pairs, n) m/rad :meth:`sim2real.deploy.safety.local_reach.LocalReach.speeds` at the centre,
        computed when not given), never above the chain bound ``weights @ half``; for the
        workspace margins the chain bound or the local bound
        ``|J(c)| @ half + half @ L @ half / 2`` (``J`` the end effector's translation Jacobian
        at the centre, ``L_ij = min(lever_i, lever_j)`` a bound of the second derivatives of
        its position along a chain of revolute joints), whichever is smaller."""
        if kind == ek.COLLISION:
            if speeds is None:
                speeds = self.local.speeds(centre)
            local, out = self.local, np.empty(self.pairs)
            return ek.pairs_reach(self.weights, speeds, half, local.order, local.nest, out)
        reach = self.weights[self.pairs :] @ half
        jacobian = pin.computeFrameJacobian(
            self.model, self.data, centre, self.robot.ee_frame_id, pin.LOCAL_WORLD_ALIGNED
        )[:3]
        local = np.abs(jacobian) @ half + 0.5 * half @ self._curvature @ half
        local += self._error_weight @ half  # the error bound's change over the box
        return np.minimum(reach, local)

    def _lower_bounds(self, kind: int, centre, half, value, speeds=None) -> np.ndarray:
        """m, a lower bound of each quantity of ``kind`` (the pairs' distances, or the workspace
        margins; ``value`` at the centre) over the box ``centre +- half`` (n,) rad: ``value``
        less :meth:`_reach` (``speeds`` as there); for a pair with a table, its bound over the box
        (:func:`sim2real.deploy.safety.pair_grid.table_bound`) where that is higher."""
        bound = value - self._reach(kind, centre, half, speeds)
        if kind == ek.COLLISION:
            for p in np.flatnonzero(self.tables.offset[:, 0] >= 0):
                table = table_bound(self.tables, p, centre, half, self.weights[p])
                bound[p] = np.fmax(bound[p], table)
        return bound

    def _certified(self, kind: int, centre, half, value, speeds=None) -> bool:
        """Whether the box ``centre +- half`` (n,) rad keeps every quantity of ``kind`` (the
        pairs' distances, or the workspace margins; ``value`` at the centre) above the margin
        (:meth:`_lower_bounds`, ``speeds`` as there). Without ``speeds``, the chain bound is
        tried first (the local bound is never lower: the same answer, without the speeds'
        Pinocchio call where the chain bound suffices)."""
        if kind == ek.COLLISION and speeds is None:
            chain = self._lower_bounds(kind, centre, half, value, self.weights[: self.pairs])
            if np.all(chain > self.margin):
                return True
        bound = self._lower_bounds(kind, centre, half, value, speeds)
        return bool(np.all(bound > self.margin))

    def _path_certified(
        self, kind: int, q, start, end, velocity, acceleration, share, reversal, widen
    ) -> bool:
        """Whether the motion is safe segment by segment: the step (``start`` to ``end``, with
        the estimate ``q``), then the brake from ``end`` at ``velocity``, ``acceleration`` (n,)
        cut into :data:`PATH_SEGMENTS` by time; each joint moves monotonically within a brake
        segment (up to ``reversal`` (n,) rad, the ``back`` of
        :func:`sim2real.deploy.safety.envelope_kernel.brake_reach`), so the boxes of the segments cover the
        path that the whole box over-covers. The brake is Ruckig's own (velocity interface to
        rest; deceleration times ``share`` (n,), the derated drives' headroom, as the kernel
        computed both)."""
        query = self.distances if kind == ek.COLLISION else self.workspace_margin
        inp = self._path_inp
        inp.current_position = end
        inp.current_velocity = velocity
        inp.current_acceleration = acceleration
        inp.max_acceleration = self.limits[0] * share
        try:
            result = self._path_ruckig.calculate(inp, self._path)
        except RuckigError:
            return False
        if result not in (Result.Working, Result.Finished):
            return False
        times = np.linspace(0.0, self._path.duration, PATH_SEGMENTS + 1)
        points = [np.asarray(self._path.at_time(t)[0]) for t in times]
        # the joints lag their command (a position servo): each segment also holds the points
        # up to the present lag behind it
        slack = reversal + np.abs(q - start)
        segments = [
            (
                np.minimum(np.minimum(q, start), end) - widen,
                np.maximum(np.maximum(q, start), end) + widen,
            )
        ]
        for a, b in zip(points[:-1], points[1:], strict=True):
            segments.append((np.minimum(a, b) - slack, np.maximum(a, b) + slack))
        for lo, hi in segments:
            c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
            if not self._certified(kind, c, h, query(c)):
                return False
        return True

    def _escapes_contact(self, start, end, rest) -> bool:
        """Whether a robot already within the margin at ``start`` moves back out: no pair's
        distance at the step's ``end`` or the brake's ``rest`` below its distance at ``start``,
        and no pair brought within the margin. False when ``start`` is clear of the margin (the
        motion, not the pose, is what fails)."""
        d0 = self.distances(start)
        if d0.min() > self.margin:
            return False
        floor = np.where(d0 > self.margin, self.margin, d0 + self._escape) - DISTANCE_TOLERANCE
        return bool(np.all(self.distances(end) >= floor) and np.all(self.distances(rest) >= floor))

    def _escapes_box(self, start, end, rest) -> bool:
        """:meth:`_escapes_contact` for the workspace box: the margin inside it may not shrink."""
        m0 = self.workspace_margin(start).min()
        if m0 > self.margin:
            return False
        m0 += self._escape - DISTANCE_TOLERANCE
        return self.workspace_margin(end).min() >= m0 and self.workspace_margin(rest).min() >= m0
