"""Lower bounds of the collision pairs' distances at a joint configuration, compiled, for the
violation monitor's self-collision check (:class:`sim2real.deploy.monitors.violations.
ViolationMonitor`): coal runs only where a bound says a pair may touch.

The monitor's joint-motion screen (:func:`sim2real.deploy.monitors.kernel.collision_screen`)
keeps a pair apart while the joints have moved less since its last measured distance than that
distance allows. A walking robot's legs move past that bound every tick, so coal used to run
every tick. :class:`PairBounds` measures instead, in one compiled call, a lower bound of each
pair's distance at the configuration itself (:func:`pair_lower_bounds`; the pairs the motion
since the last call may have brought near, the others keep their bound less that motion's): the
forward kinematics of the guard's fixed-base Pinocchio model (revolute joints), then per pair
of its coal geometries

- two capsules or spheres (a sphere: a capsule of length 0): the distance of their segments less
  both radii (exact up to round-off);
- a box and a capsule, sphere or box: the largest gap between their projections on the box's
  axes, the other box's axes, the line between the two centres and (a box and a capsule) the
  line between their nearest points (a separating axis: a gap along a unit axis is at most the
  distance).

Coal answers "no contact" for a pair whose distance exceeds ``APART`` (its collision query
reports contact only at a distance of 0 and below, within its GJK tolerance, 1e-6 m: coal's
``CollisionRequest.gjk_tolerance`` default, read back by ``tests/test_pair_bounds.py``), so a
pair with a bound above ``APART`` needs no coal: the monitor's answers are the same.
A model with another joint or geometry type gets no bounds (``PairBounds.build`` returns None):
coal checks it as before.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pinocchio as pin

#: m: a pair whose lower bound exceeds this is not in contact for coal (see the module
#: docstring): 100 x coal's GJK tolerance (1e-6 m, its default), far above the bounds' round-off.
APART = 1e-4
#: geometry kinds of the kernel
CAPSULE, BOX = 0, 1
#: joint axes: a revolute joint about x, y, z, or about ``axis`` (Pinocchio's unaligned one)
_AXES = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2, "JointModelRevoluteUnaligned": 3}


class PairBounds:
    """The arrays of :func:`pair_lower_bounds` for one guard collision model (see the module
    docstring); :meth:`build` makes it.

    Attributes:
        joints: (J, 4) int64 per Pinocchio joint after the universe: parent joint index, index
            of its angle in ``q``, axis kind (0 x, 1 y, 2 z, 3 ``axis``), unused.
        joint_frames: (J, 4, 3) float64: the joint's placement in its parent (rotation rows 0-2,
            translation row 3) and its ``axis`` (row 3 of ``joint_axes``, (J, 3)).
        geoms: (G, 2) int64: parent joint (0: the fixed base), kind (``CAPSULE``, ``BOX``).
        geom_frames: (G, 4, 3) float64: placement in the parent joint (rotation, translation).
        shapes: (G, 4) float64: a capsule's radius and half length (a sphere's: 0); a box's
            half sides (rows 1-3).
        pairs: (P, 2) int64, the geometries of each collision pair (coal's order).
    """

    def __init__(self, joints, joint_frames, joint_axes, geoms, geom_frames, shapes, pairs):
        self.joints, self.joint_frames, self.joint_axes = joints, joint_frames, joint_axes
        self.geoms, self.geom_frames, self.shapes, self.pairs = geoms, geom_frames, shapes, pairs
        self.frames = np.zeros((len(joints) + 1, 4, 3))  # the kinematics' scratch
        self.frames[0, :3] = np.eye(3)
        self.placed = np.zeros((len(geoms), 4, 3))

    @classmethod
    def build(cls, model: pin.Model, geom_model: pin.GeometryModel) -> PairBounds | None:
        """The bounds of ``geom_model``'s collision pairs on ``model`` (the guard's fixed-base
        model), or None where a joint is not revolute (one angle) or a geometry of a pair is not
        a capsule, sphere or box. Raises nothing."""
        njoints = model.njoints - 1
        joints = np.zeros((njoints, 4), np.int64)
        joint_frames = np.zeros((njoints, 4, 3))
        joint_axes = np.zeros((njoints, 3))
        for i in range(1, model.njoints):
            kind = _AXES.get(model.joints[i].shortname())
            if kind is None or model.joints[i].nq != 1:
                return None
            joints[i - 1, :3] = (model.parents[i], model.idx_qs[i], kind)
            placement = model.jointPlacements[i]
            joint_frames[i - 1, :3], joint_frames[i - 1, 3] = (
                placement.rotation,
                placement.translation,
            )
            if kind == 3:
                joint_axes[i - 1] = model.joints[i].extract().axis
        objects = geom_model.geometryObjects
        geoms = np.zeros((len(objects), 2), np.int64)
        geom_frames = np.zeros((len(objects), 4, 3))
        shapes = np.zeros((len(objects), 4))
        used = {g for p in geom_model.collisionPairs for g in (p.first, p.second)}
        for g, obj in enumerate(objects):
            geoms[g, 0] = obj.parentJoint
            geom_frames[g, :3], geom_frames[g, 3] = (
                obj.placement.rotation,
                obj.placement.translation,
            )
            shape = obj.geometry
            name = type(shape).__name__
            if name == "Capsule":
                geoms[g, 1], shapes[g, :2] = CAPSULE, (shape.radius, shape.halfLength)
            elif name == "Sphere":
                geoms[g, 1], shapes[g, :2] = CAPSULE, (shape.radius, 0.0)
            elif name == "Box":
                geoms[g, 1], shapes[g, 1:] = BOX, shape.halfSide
            elif g in used:
                return None
        pairs = np.array([(p.first, p.second) for p in geom_model.collisionPairs], np.int64)
        return cls(
            joints, joint_frames, joint_axes, geoms, geom_frames, shapes, pairs.reshape(-1, 2)
        )

    def arrays(self) -> tuple:
        """The arrays :func:`pair_lower_bounds` takes after ``q``, in its order."""
        return (
            self.joints, self.joint_frames, self.joint_axes, self.geoms, self.geom_frames,
            self.shapes, self.pairs, self.frames, self.placed,
        )  # fmt: skip


@numba.njit(cache=True, nogil=True, _nrt=False)
def _compose(parent, local, out) -> None:
    """``out`` = ``parent * local`` of two placements (4, 3): rotation rows 0-2, translation
    row 3."""
    for i in range(3):
        for j in range(3):
            out[i, j] = (
                parent[i, 0] * local[0, j] + parent[i, 1] * local[1, j] + parent[i, 2] * local[2, j]
            )
        out[3, i] = (
            parent[3, i]
            + parent[i, 0] * local[3, 0]
            + parent[i, 1] * local[3, 1]
            + parent[i, 2] * local[3, 2]
        )


@numba.njit(cache=True, nogil=True, _nrt=False)
def _turn(frame, kind: int, axis, angle: float) -> None:
    """``frame``'s rotation (rows 0-2 of (4, 3)) times the rotation by ``angle`` about its
    joint's axis (``kind`` 0-2: x, y, z; 3: the unit ``axis``), in place."""
    c, s = math.cos(angle), math.sin(angle)
    if kind == 3:
        x, y, z = axis[0], axis[1], axis[2]
    else:
        x = 1.0 if kind == 0 else 0.0
        y = 1.0 if kind == 1 else 0.0
        z = 1.0 if kind == 2 else 0.0
    t = 1.0 - c
    r00, r01, r02 = t * x * x + c, t * x * y - s * z, t * x * z + s * y
    r10, r11, r12 = t * x * y + s * z, t * y * y + c, t * y * z - s * x
    r20, r21, r22 = t * x * z - s * y, t * y * z + s * x, t * z * z + c
    for i in range(3):
        a, b, d = frame[i, 0], frame[i, 1], frame[i, 2]
        frame[i, 0] = a * r00 + b * r10 + d * r20
        frame[i, 1] = a * r01 + b * r11 + d * r21
        frame[i, 2] = a * r02 + b * r12 + d * r22


@numba.njit(cache=True, nogil=True, _nrt=False)
def _segment_distance(p, u, q, v) -> float:
    """The distance between the segments ``p + s u`` and ``q + t v``, ``s, t`` in [0, 1] (the
    closest points of two segments: Ericson, Real-Time Collision Detection, 5.1.9)."""
    rx, ry, rz = p[0] - q[0], p[1] - q[1], p[2] - q[2]
    a = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    e = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    f = v[0] * rx + v[1] * ry + v[2] * rz
    s = t = 0.0
    if a <= 1e-300 and e <= 1e-300:
        pass
    elif a <= 1e-300:
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = u[0] * rx + u[1] * ry + u[2] * rz
        if e <= 1e-300:
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
            denom = a * e - b * b
            s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t, s = 0.0, min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t, s = 1.0, min(max((b - c) / a, 0.0), 1.0)
    dx = rx + s * u[0] - t * v[0]
    dy = ry + s * u[1] - t * v[1]
    dz = rz + s * u[2] - t * v[2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@numba.njit(cache=True, nogil=True, _nrt=False)
def _extent(frame, kind: int, shape, ax, ay, az) -> tuple:
    """The interval of a placed geometry's projection on the unit axis ``(ax, ay, az)``."""
    centre = frame[3, 0] * ax + frame[3, 1] * ay + frame[3, 2] * az
    if kind == BOX:
        half = 0.0
        for i in range(3):  # the box's local axis i: column i of its rotation
            half += shape[1 + i] * abs(frame[0, i] * ax + frame[1, i] * ay + frame[2, i] * az)
        return centre - half, centre + half
    # a capsule along its local z, half length shape[1], radius shape[0]
    reach = shape[1] * abs(frame[0, 2] * ax + frame[1, 2] * ay + frame[2, 2] * az)
    return centre - reach - shape[0], centre + reach + shape[0]


@numba.njit(cache=True, nogil=True, _nrt=False)
def _gap(fa, ka: int, sa, fb, kb: int, sb, ax, ay, az) -> float:
    """The gap between two placed geometries' projections on ``(ax, ay, az)`` (normalized
    here; a null axis: -inf)."""
    norm = math.sqrt(ax * ax + ay * ay + az * az)
    if norm < 1e-12:
        return -np.inf
    ax, ay, az = ax / norm, ay / norm, az / norm
    lo_a, hi_a = _extent(fa, ka, sa, ax, ay, az)
    lo_b, hi_b = _extent(fb, kb, sb, ax, ay, az)
    return max(lo_b - hi_a, lo_a - hi_b)


@numba.njit(cache=True, nogil=True, _nrt=False)
def _closest_line(box, half, cap, length: float) -> tuple:
    """The direction from a placed box (half sides ``half[1:]``) to a placed capsule's segment
    (half length ``length``) between the points four alternating projections reach (the
    nearest points where they converge): an axis for :func:`_gap`, a bound however near."""
    px, py, pz = cap[3, 0], cap[3, 1], cap[3, 2]  # from the segment's centre
    bx = by = bz = 0.0
    for _ in range(4):
        dx, dy, dz = px - box[3, 0], py - box[3, 1], pz - box[3, 2]
        bx, by, bz = box[3, 0], box[3, 1], box[3, 2]
        for i in range(3):  # the box's point nearest p: clamped along each of its axes
            c = box[0, i] * dx + box[1, i] * dy + box[2, i] * dz
            c = min(max(c, -half[1 + i]), half[1 + i])
            bx, by, bz = bx + c * box[0, i], by + c * box[1, i], bz + c * box[2, i]
        s = (bx - cap[3, 0]) * cap[0, 2] + (by - cap[3, 1]) * cap[1, 2]
        s = min(max(s + (bz - cap[3, 2]) * cap[2, 2], -length), length)  # nearest b (unit z)
        px, py, pz = cap[3, 0] + s * cap[0, 2], cap[3, 1] + s * cap[1, 2], cap[3, 2] + s * cap[2, 2]
    return px - bx, py - by, pz - bz


@numba.njit(cache=True, nogil=True, _nrt=False)
def _pair_bound(fa, ka: int, sa, fb, kb: int, sb, apart: float) -> float:
    """A lower bound of the distance of two placed geometries (see the module docstring); of a
    box, from its first axes that put it past ``apart`` (m)."""
    if ka == CAPSULE and kb == CAPSULE:
        ha, hb = sa[1], sb[1]
        pa = (fa[3, 0] - ha * fa[0, 2], fa[3, 1] - ha * fa[1, 2], fa[3, 2] - ha * fa[2, 2])
        ua = (2.0 * ha * fa[0, 2], 2.0 * ha * fa[1, 2], 2.0 * ha * fa[2, 2])
        pb = (fb[3, 0] - hb * fb[0, 2], fb[3, 1] - hb * fb[1, 2], fb[3, 2] - hb * fb[2, 2])
        ub = (2.0 * hb * fb[0, 2], 2.0 * hb * fb[1, 2], 2.0 * hb * fb[2, 2])
        return _segment_distance(pa, ua, pb, ub) - sa[0] - sb[0]
    best = -np.inf
    if ka != kb:  # a box and a capsule: the line between their nearest points, nearly
        if ka == BOX:
            ax, ay, az = _closest_line(fa, sa, fb, sb[1])
        else:
            ax, ay, az = _closest_line(fb, sb, fa, sa[1])
            ax, ay, az = -ax, -ay, -az
        best = _gap(fa, ka, sa, fb, kb, sb, ax, ay, az)
        if best > apart:  # enough: the other axes only for a pair this one leaves near
            return best
    dx, dy, dz = fb[3, 0] - fa[3, 0], fb[3, 1] - fa[3, 1], fb[3, 2] - fa[3, 2]
    best = max(best, _gap(fa, ka, sa, fb, kb, sb, dx, dy, dz))
    for i in range(3):
        if ka == BOX:
            best = max(best, _gap(fa, ka, sa, fb, kb, sb, fa[0, i], fa[1, i], fa[2, i]))
        if kb == BOX:
            best = max(best, _gap(fa, ka, sa, fb, kb, sb, fb[0, i], fb[1, i], fb[2, i]))
    return best


@numba.njit(cache=True, nogil=True, _nrt=False)
def pair_lower_bounds(
    q, joints, joint_frames, joint_axes, geoms, geom_frames, shapes, pairs, frames, placed,
    weights, margin: float, checked_q, clearance, apart: float, e: int,
) -> bool:  # fmt: skip
    """Each collision pair's lower bound of its distance (m) at env ``e``'s joint angles
    ``q[e]`` (rad), less ``apart``, into ``clearance[e]`` ((envs, P) m) and ``q[e]`` into
    ``checked_q[e]`` ((envs, n) rad; the monitor's joint-motion screen reads both), with the
    arrays of :meth:`PairBounds.arrays`; returns whether some pair's bound is ``apart`` or less
    (it may touch: coal must check). A pair the joints' motion since ``checked_q[e]`` cannot
    have brought within its clearance (``weights`` (P, n) m/rad, the screen's
    :func:`sim2real.robots.chain_bounds.collision_pair_weights`, and its ``margin`` m) keeps
    that clearance less the motion's bound and ``margin``, unmeasured."""
    n = q.shape[1]
    placed_now = False
    near = False
    for p in range(pairs.shape[0]):
        moved = 0.0
        for j in range(n):
            moved += abs(q[e, j] - checked_q[e, j]) * weights[p, j]
        if clearance[e, p] > moved + margin:  # still apart: the bound follows the motion
            clearance[e, p] -= moved + margin
            continue
        if not placed_now:
            _place(q, e, joints, joint_frames, joint_axes, geoms, geom_frames, frames, placed)
            placed_now = True
        a, b = pairs[p, 0], pairs[p, 1]
        d = _pair_bound(placed[a], geoms[a, 1], shapes[a], placed[b], geoms[b, 1], shapes[b], apart)
        clearance[e, p] = d - apart
        near = near or not d > apart  # NaN: may touch
    for j in range(n):
        checked_q[e, j] = q[e, j]
    return near


@numba.njit(cache=True, nogil=True, _nrt=False)
def _place(q, e, joints, joint_frames, joint_axes, geoms, geom_frames, frames, placed) -> None:
    """The geometries' placements at ``q[e]`` into ``placed`` (the joints' into ``frames``)."""
    for i in range(joints.shape[0]):  # the joints in Pinocchio's order: parents first
        _compose(frames[joints[i, 0]], joint_frames[i], frames[i + 1])
        _turn(frames[i + 1], joints[i, 2], joint_axes[i], q[e, joints[i, 1]])
    for g in range(geoms.shape[0]):
        _compose(frames[geoms[g, 0]], geom_frames[g], placed[g])
