"""The exact (Pinocchio, coal) side of the motion envelope: the queries at one configuration
and the certification of a box or a path the compiled screen could not certify.

:class:`EnvelopeQueries` is a base class of
:class:`~sim2real.deploy.safety.envelope.MotionEnvelope` (whose docstring says how a motion is
certified); its methods work on the envelope's attributes, set in ``MotionEnvelope.__init__``.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from ruckig import Result, RuckigError

from sim2real.deploy.safety import envelope_kernel as ek
from sim2real.deploy.safety.pair_grid import table_bound

#: m, distances within this of each other are equal (coal's round-off between configurations
#: that leave a pair's relative pose unchanged).
DISTANCE_TOLERANCE = 1e-9
#: m, how much deeper than where it began a position servo's path back into its workspace box
#: may go (our choice: so101 slumped under gravity in the Feetech emulator for 3 to 15 s, its
#: end effector 1.5 to 16 cm below its box's floor, dipped up to 8.3 mm on the smoother's way
#: home, whose joints move unsynchronised; its box leaves 5 cm below the base).
ESCAPE_DEPTH = 0.02
#: Segments of the brake the path certification cuts by time (our choice: a few Pinocchio
#: calls, only where the whole box is uncertain).
PATH_SEGMENTS = 4


class EnvelopeQueries:
    """The exact queries and certifications of a
    :class:`~sim2real.deploy.safety.envelope.MotionEnvelope` (module docstring)."""

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

    # ------------------------------------------------------------------ exact certification
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
        return self._escapes_box(e, start, end, rest)

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

    def _escapes_box(self, e: int, start, end, rest) -> bool:
        """:meth:`_escapes_contact` for the workspace box: the margin inside it (its smallest axis,
        m, negative outside) may not shrink at the step's ``end`` or the brake's ``rest``. A
        position servo's (no drive model, no torque: ``start`` is its command path, free of the
        estimate's noise) may instead stay above env ``e``'s floor (:attr:`escape_floor`),
        :data:`ESCAPE_DEPTH` below the start and only rising while it escapes (a start below it
        begins a new escape: something else, a push, moved the arm). A path back into the box
        from a pose outside it is seldom monotone: the smoother's joints move unsynchronised (a
        joint with little way to go arrives first), and even a straight line in joint space may
        dip before it rises (so101 slumped below its box's floor, ramping in to home: up to
        8.3 mm); refusing every dip held the ramp at its start forever. The floor never falls
        along accepted steps, so repeated dips cannot creep outward. False when ``start`` is clear
        of the margin (the motion, not the pose, is what fails)."""
        m0 = self.workspace_margin(start).min()
        if m0 > self.margin:
            return False
        if self.drive is None and self.torque is None:
            floor = self.escape_floor
            lowest = m0 - ESCAPE_DEPTH
            floor[e] = lowest if not m0 >= floor[e] else max(floor[e], lowest)
            m0 = floor[e]
        m0 += self._escape - DISTANCE_TOLERANCE
        return self.workspace_margin(end).min() >= m0 and self.workspace_margin(rest).min() >= m0
