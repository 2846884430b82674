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

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    Ruckig,
    Synchronization,
    Trajectory,
)

from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.safety import certify_table
from sim2real.deploy.safety import envelope_kernel as ek
from sim2real.deploy.safety.envelope_query import EnvelopeQueries
from sim2real.deploy.safety.local_reach import LocalReach
from sim2real.deploy.safety.pair_grid import PairTables, pair_grids
from sim2real.robots.chain_bounds import axis_levers

#: m, default clearance kept between listed collision geometries and from the workspace box's
#: faces: our choice, a few times the joint estimate's error times a lever of about a metre, plus
#: the position servo's deviation from the box of its command path; capped at half the home
#: pose's own clearance (see ``MotionEnvelope``).
DEFAULT_MARGIN = 0.01
#: Smallest share of the full deceleration the envelope assumes of a derated drive (our choice: a
#: drive derated to its floor still holds the arm; its brake is taken as 20 times longer).
MIN_HEADROOM = 0.05
#: m, how much a robot within the margin must gain back per step in torque mode (our choice,
#: about the estimate's noise times a lever of a metre): the start of a torque step is the noisy
#: estimate, and "no closer than now" then let a ur5 pressed down by its policy random-walk
#: through its box's floor; a servo's command path has no such noise.
TORQUE_ESCAPE = 1e-3


class MotionEnvelope(EnvelopeQueries):
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
    (its queries' ``_reach``). A pair moved by at most two joints also has a table of lower
    bounds over a grid of those joints (:mod:`sim2real.deploy.safety.pair_grid`): its distance stays above
    the least bound of the cells the box covers, which certifies boxes the chain bound does not
    where the distance hardly changes with a joint (the SO-101's base about its pan axis); the
    higher of the two bounds counts. The same bounds screen each box against the last query, so far
    from contact no query runs (the decision is the same with or without that cache). A box one
    query cannot certify over-covers the motion (its corners combine one joint's start with
    another's end): the step and Ruckig's own brake are then cut into
    :data:`~sim2real.deploy.safety.envelope_query.PATH_SEGMENTS` by time, each joint monotonic
    within one, and each segment is certified (:mod:`~sim2real.deploy.safety.envelope_query`).
    Workspace faces beyond the end effector's reach are never crossed and not checked.

    By induction the brake is always safe to take: the previous tick certified the motion that holds
    it. A robot already within the margin (pushed there, or started there) may only move so that no
    pair's distance and no workspace margin shrinks, checked at the step's end and at its brake's
    rest point; otherwise it brakes (a position servo's workspace margin may dip, never below a
    rising floor, :attr:`escape_floor`: an arm started outside its box ramps back in).

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
        #: (envs,) m, position mode: the margin an env escaping into its box may not go below
        #: (``EnvelopeQueries._escapes_box``); NaN: none yet
        self.escape_floor = np.full(envs, np.nan)
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
        if self.has_workspace:
            self._set_workspace(reach, s)
        self._set_limits(gravity_bound, torque)
        self._set_pair_bounds(geometry, pair_weights)
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
        self._set_query_cache(pair_weights)
        self._set_brake_path()
        # envelope_screen's arrays after effort_scale (the tables' and the margin as of the
        # last certify's binding: a test may replace them after construction)
        self._screen = ek.ScreenArrays(
            self.limits, self._cached_q, self._clearance, self.weights, self.margin, self._box,
            self._need, *self.tables.arrays(), self._speeds, self.local.order, self.local.nest,
            self._slack, self._lead, np.zeros((2, n)),
        )  # fmt: skip
        self._certify_key = (None,) * 10  # certify's kernel bound to these arrays
        self._certify = self._dynamics = None
        ek.warm_up()
        self._warm_certify()

    def _set_workspace(self, reach: float, s) -> None:
        """The workspace box (``ws_min``, ``ws_max``, m): a face beyond the longest chain's reach
        (lengthened by the link tolerance) can never be crossed and is left out (infinite)."""
        reach = (1.0 + self.link_length_tolerance) * reach
        self.ws_min = np.where(np.array(s.workspace_min) <= -reach, -np.inf, s.workspace_min)
        self.ws_max = np.where(np.array(s.workspace_max) >= reach, np.inf, s.workspace_max)

    def _set_limits(self, gravity_bound, torque) -> None:
        """``limits`` (4, n): the smoother's acceleration and jerk limits (torque mode: the
        guard's computed-torque stop's), the worst gravity load's share of each effort limit,
        ``MIN_HEADROOM``."""
        n = self.robot.n_joints
        self.limits = np.stack(
            [
                self.robot.acceleration_limit,
                self.robot.jerk_limit,
                np.asarray(gravity_bound) / self.robot.effort_limit,
                np.full(n, MIN_HEADROOM),
            ]
        )
        if torque is not None:  # the guard's computed-torque stop, not the smoother's brake
            self.limits[:2] = torque.brake_limits

    def _set_pair_bounds(self, geometry, pair_weights) -> None:
        """The collision pairs' bounds: those kept apart, the lower-bound tables, the local
        approach bounds."""
        #: (pairs,) bool, the pairs the joints between their links cannot bring into contact
        #: (:func:`sim2real.deploy.safety.pair_grid.pairs_kept_apart`): left out of the certification (their
        #: distance reads as infinite), so a gripper's jaw closing next to its wrist brakes nothing
        self.apart = np.zeros(0, dtype=bool)
        #: the other pairs' lower-bound tables over the joints that move them
        #: (:class:`sim2real.deploy.safety.pair_grid.PairTables`), from the same grids
        self.tables = PairTables.empty(self.pairs)
        if self.pairs:
            self.apart, self.tables = pair_grids(self.robot, geometry, pair_weights)
        #: the pairs' local approach bounds (:class:`sim2real.deploy.safety.local_reach.LocalReach`)
        self.local = LocalReach(self.robot, geometry)
        self.queries = 0

    def _set_query_cache(self, pair_weights) -> None:
        """The cache of the last exact query and the screen's per-env work arrays."""
        envs, n = self.envs, self.robot.n_joints
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

    def _set_brake_path(self) -> None:
        """Ruckig's brake path to rest (:meth:`_path_certified`) and the per-env flags, slack
        and lead of the screen."""
        envs, n = self.envs, self.robot.n_joints
        # the brake's path (_path_certified): Ruckig to rest, one env's joints at a time
        self._path_ruckig = Ruckig(n)
        self._path = Trajectory(n)
        self._path_inp = inp = InputParameter(n)
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.No
        inp.max_velocity = 2.0 * np.asarray(self.robot.velocity_limit)
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

    def _warm_certify(self) -> None:
        """Compile (or load numba's cache of) :meth:`certify`'s kernel now, not in a tick, for
        the runtime's arrays' types, on copies."""
        envs, n = self.envs, self.robot.n_joints
        z, z3 = np.zeros((envs, n)), np.zeros((3, envs, n))
        state = (z, z.copy(), z3, z3.copy(), np.zeros(envs, dtype=bool), np.ones((envs, n)))
        s = self._screen  # copies of what the kernel writes; the rest as it is (its types)
        screen = s._replace(box=s.box.copy(), need=s.need.copy(), slack=s.slack.copy(),
                            lead=s.lead.copy(), scratch=s.scratch.copy())  # fmt: skip
        drive, arrays = self.drive, None
        if drive is not None:
            arrays = self._drive_arrays(z)._replace(
                setpoint=drive.setpoint.copy(), path=self._drive_path.copy(),
                beyond=self.beyond.copy(),
            )  # fmt: skip
        ek.certify(*state, z.copy(), screen, arrays)
        if arrays is not None:  # the table's kernel, for the speed's variance of any layout
            arrays = arrays._replace(variance=np.ascontiguousarray(arrays.variance))
        table = certify_table.build((*state, z.copy()), screen, arrays)
        if table is not None:
            certify_table.kernel(table)(table)

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
            self._clear()
        if self.torque is not None:
            before, after, slack = self.torque.motion(q, dq, command)
            np.copyto(self._slack, slack)
        elif self.drive is not None:
            before, after = self._drive_motion(q, dq, before, after, effort_scale, stopping)
        screen = self._screen._replace(margin=self.margin, **self._tables_dict())
        uncertain = ek.envelope_screen(
            q, before, after, stopping, screen.limits, effort_scale, *screen[1:]
        )
        return self._decide(q, before, after, stopping, uncertain)

    def _clear(self) -> None:
        """Forget the last unsafe check's :attr:`unsafe`, :attr:`joints` and :attr:`beyond`."""
        self.unsafe.fill(False)
        self.joints.fill(False)
        self.beyond.fill(False)
        self._dirty = False

    def _decide(self, q, before, after, stopping, uncertain: bool) -> bool:
        """:meth:`check` after the screen (``uncertain``: some env needs an exact query):
        :attr:`beyond`'s joints, the exact queries; returns whether any env is unsafe."""
        box, need = self._box, self._need
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

    def certify(self, q, dq, before, after, stopping, effort_scale, command) -> bool:
        """:meth:`check` of the smoother's step and, unless some env is unsafe, :meth:`commit`
        of ``command`` (envs, n): one compiled call (:func:`sim2real.deploy.safety.envelope_kernel.
        certify`, bound to the arrays of the last call, :mod:`sim2real.deploy.kernels.calls`) where
        the screen certifies every env, besides a velocity drive's Pinocchio calls. Arguments as
        :meth:`check`'s (``dq`` and ``command`` required).

        Returns:
            Whether any env is unsafe (:attr:`unsafe`, :attr:`joints`, :attr:`beyond` as after
            :meth:`check`): the caller brakes those envs and commits the command itself.
        """
        if self.torque is None:
            key, drive = self._certify_key, self.drive
            if (
                q is not key[0] or dq is not key[1] or before is not key[2]
                or after is not key[3] or stopping is not key[4] or effort_scale is not key[5]
                or command is not key[6] or self.tables is not key[7]
                or self.margin is not key[8]
                or (drive is not None and drive.speed_variance is not key[9])
            ):  # fmt: skip
                self._bind_certify(q, dq, before, after, stopping, effort_scale, command)
            return self._run_certify(q, before, after, stopping, command)
        dirty = self.check(q, before, after, stopping, effort_scale, dq=dq, command=command)
        if not dirty:
            self.commit(command)
        return dirty

    def certifier(self, q, dq, before, after, stopping, effort_scale, command):
        """``() -> bool``, :meth:`certify` of these arrays (the same arguments) bound to them for
        a caller that passes the same ones every tick: the identity checks of :meth:`certify`
        are left out but for the arrays a test or :meth:`sim2real.deploy.safety.guard.SafetyGuard.
        trust_estimate` may replace (the pair tables, the margin, the speed's variance); any
        other call of :meth:`certify` in between makes it call :meth:`certify` itself."""
        args = (q, dq, before, after, stopping, effort_scale, command)
        if self.torque is not None:
            return lambda: self.certify(*args)
        self._bind_certify(*args)
        key, drive = self._certify_key, self.drive
        dynamics, kernel = self._dynamics, self._certify  # as bound with key (checked below)
        q, before, after, stopping, command = args[0], args[2], args[3], args[4], args[6]

        def certify() -> bool:
            if (
                self._certify_key is not key or self.tables is not key[7]
                or self.margin is not key[8]
                or (drive is not None and drive.speed_variance is not key[9])
            ):  # fmt: skip
                return self.certify(*args)
            if self._dirty:  # _run_certify, inline
                self._clear()
            if drive is not None:
                dynamics()
            code = kernel()
            return self._coded(code, q, before, after, stopping, command) if code else False

        return certify

    def _run_certify(self, q, before, after, stopping, command) -> bool:
        """:meth:`certify` once its kernel is bound to these arrays: the velocity drive's
        Pinocchio calls, the kernel, and where it does not certify every env, :meth:`_decide`
        (and the commit when that finds none unsafe)."""
        if self._dirty:
            self._clear()
        drive = self.drive
        if drive is not None:
            self._dynamics()
        code = self._certify()
        if not code:
            return False  # certified and committed
        return self._coded(code, q, before, after, stopping, command)

    def _coded(self, code: int, q, before, after, stopping, command) -> bool:
        """:meth:`_run_certify` after a kernel's ``code`` that did not certify every env."""
        drive = self.drive
        if drive is not None:
            before, after = self._drive_path[0], self._drive_path[1]
            self._drive_beyond = bool(code & ek.BEYOND)
        dirty = self._decide(q, before, after, stopping, bool(code & ek.UNCERTAIN))
        if not dirty:
            self.commit(command)
        return dirty

    def _bind_certify(self, q, dq, before, after, stopping, effort_scale, command) -> None:
        """Bind :meth:`certify`'s kernel to these arrays (and the velocity drive's Pinocchio
        calls to ``q``)."""
        drive = self.drive
        self._screen = self._screen._replace(margin=self.margin, **self._tables_dict())
        arrays = self._drive_arrays(q) if drive is not None else None
        args = (q, dq, before, after, stopping, effort_scale, command)
        self._certify = bind(ek.certify, *args, self._screen, arrays)
        table = certify_table.build(args, self._screen, arrays)  # one array, not thirty
        if table is not None:
            self._certify = bind(certify_table.kernel(table), table)
        variance = drive.speed_variance if drive is not None else None
        self._certify_key = (*args, self.tables, self.margin, variance)

    def _drive_arrays(self, q) -> ek.DriveArrays:
        """The velocity drive's :class:`~sim2real.deploy.safety.envelope_kernel.DriveArrays`
        for the estimate ``q`` (its Pinocchio calls bound to it: ``_dynamics``)."""
        drive = self.drive
        self._dynamics, gravity, mass = drive.dynamics_at(q)
        return ek.DriveArrays(
            drive.setpoint, gravity, mass, drive.joint_figures, drive.speed_variance, drive.uncertainty,
            drive.dt, drive.lower, drive.upper, self._drive_path, self.beyond,
        )  # fmt: skip

    def _tables_dict(self) -> dict:
        """The pair tables' arrays (:class:`sim2real.deploy.safety.pair_grid.PairTables`) by their
        names in :class:`~sim2real.deploy.safety.envelope_kernel.ScreenArrays`."""
        return dict(
            zip(("joint", "grid", "cells", "offset", "values"), self.tables.arrays(), strict=True)
        )

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
