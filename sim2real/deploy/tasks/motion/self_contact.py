"""The clip's own self-contacts: the reference posed frame by frame against the robot's collision
model, before it plays.

A description's collision geometry can make a reference motion touch itself: unitree_mujoco's
G1 collides the convex hulls of its meshes, and the hull of the concave torso swallows the
shoulders and elbows that rl_sar's dance_102 brings close (599 of its 1,749 frames touch, up to
6 cm deep, in MuJoCo's own model). A robot that tracks such a clip well touches there too: the
reference's contact under this collision model, not the policy's or the runtime's doing.

:func:`clip_self_contacts` poses every frame of the clip's joint angles (robot order, the base
fixed: self-contact does not depend on it) in the violation monitor's own collision model
(:func:`sim2real.deploy.safety.collision.collision_model`: the same geoms and pairs, coal) and
keeps which pairs touch in each frame and how deep. :class:`ClipContacts` answers which pairs
the reference brings into contact around a moment (:meth:`ClipContacts.allowed`, a window of
frames either side: a tracking robot lags its reference by a few ticks); the violation monitor
counts a self-collision tick whose touching pairs are all among them apart, as the reference's
contact (:meth:`sim2real.deploy.monitors.violations.ViolationMonitor.excuse_contacts`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from sim2real.deploy.safety.collision import collision_model

#: s either side of the reference's moment within which its own contacts excuse the robot's
#: (a tracking policy lags its reference by a few control ticks: 0.2 s is 10 ticks at 50 Hz).
CONTACT_WINDOW_S = 0.2


@dataclass
class ClipContacts:
    """Which collision pairs each frame of a reference touches (:func:`clip_self_contacts`).

    Attributes:
        pair_names: (P,) ``"geom_a|geom_b"``, the violation monitor's pairs in its order.
        touching: (T, P) bool, the pairs in contact at each frame.
        depth: (T,) m, each frame's deepest penetration (0 where none touches).
        fps: Hz, the frames' rate. window: frames either side :meth:`allowed` widens by.
    """

    pair_names: list[str]
    touching: np.ndarray
    depth: np.ndarray
    fps: float
    window: int

    def __post_init__(self) -> None:
        t = self.touching
        # the dilation of touching over +-window frames, by a running count
        count = np.concatenate([np.zeros((1, t.shape[1]), np.int64), np.cumsum(t, axis=0)])
        idx = np.arange(t.shape[0])
        hi = np.minimum(idx + self.window + 1, t.shape[0])
        lo = np.maximum(idx - self.window, 0)
        self._dilated = (count[hi] - count[lo]) > 0

    def allowed(self, frame: int) -> np.ndarray:
        """(P,) bool: the pairs the reference touches within the window around ``frame``
        (clamped to the clip)."""
        return self._dilated[min(max(int(frame), 0), len(self._dilated) - 1)]

    def summary(self) -> dict:
        """``frames`` (T), ``frames_touching``, ``worst_depth_m``, ``pairs`` {name: frames},
        most first, ``window_s``."""
        frames = self.touching.sum(axis=0)
        order = np.argsort(-frames, kind="stable")
        return {
            "frames": int(self.touching.shape[0]),
            "frames_touching": int(self.touching.any(axis=1).sum()),
            "worst_depth_m": float(self.depth.max()) if len(self.depth) else 0.0,
            "pairs": {self.pair_names[k]: int(frames[k]) for k in order if frames[k] > 0},
            "window_s": self.window / self.fps,
        }


def clip_self_contacts(
    robot, joint_pos: np.ndarray, fps: float, window_s: float = CONTACT_WINDOW_S
) -> ClipContacts:
    """Pose each frame of ``joint_pos`` (T, n) rad, robot order, in the robot's collision model
    (the violation monitor's: ``safety.collision_pairs`` of robot.toml on its MJCF's geoms)
    and record its contacts (module docstring); ``fps`` Hz the frames' rate, ``window_s`` s
    either side (:meth:`ClipContacts.allowed`). A robot without pairs: nothing touches.

    Raises:
        ValueError: a listed geom not in the MJCF (:func:`collision_model`'s).
    """
    geom_model, geom_data = collision_model(robot)
    model = robot.fixed_base_model
    data = model.createData()
    objects = geom_model.geometryObjects
    names = [f"{objects[p.first].name}|{objects[p.second].name}" for p in geom_model.collisionPairs]
    frames = len(joint_pos)
    touching = np.zeros((frames, len(names)), dtype=bool)
    depth = np.zeros(frames)
    if names:
        for f in range(frames):
            if not pin.computeCollisions(model, data, geom_model, geom_data, joint_pos[f], False):
                continue
            for k, result in enumerate(geom_data.collisionResults):
                if result.isCollision():
                    touching[f, k] = True
                    # coal's signed distance of the pair: negative, the penetration
                    gap = pin.computeDistance(geom_model, geom_data, k).min_distance
                    depth[f] = max(depth[f], -gap)
    window = int(math.ceil(window_s * fps))
    return ClipContacts(names, touching, depth, float(fps), window)
