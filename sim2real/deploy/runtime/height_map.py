"""The runtime's elevation map input (:class:`HeightMap`): the scan a policy's ``height_scan`` block
reads, kept from the maps that arrive, and judged stale like any sensor.

Each tick its ``source`` (a simulated plant's ray casts,
:class:`sim2real.deploy.backends.sim.height_scan.PlantHeightScanner`; on hardware an elevation map
subscriber, :class:`sim2real.deploy.ros2.height_map.HeightMapSubscriber`) writes what arrived into
the frame's ``height_scan`` (envs, points) m and ``height_scan_stamp`` (envs,) s; a map newer
than the last one taken replaces the state's scan (:attr:`sim2real.deploy.core.state.RobotState.
height_scan`). An env whose last map is older than the robot's ``Robot.stale_limit`` (or that
has had none) is stale: the runtime safe-stops it (``stale_sensor``), as it does a silent IMU. A
policy without a ``height_scan`` block has no such stage (:func:`height_map_stage` gives None).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.stateful import put, take


class HeightMap:
    """The elevation map input of ``envs`` robots (module docstring).

    Args:
        points: The scan's points (the block's size). envs: Robots.
        stale_limit: s, a map older than this stops the robot.
        source: ``fill(frame)`` writing the frame's map each tick, or None (the backend fills the
            frame itself).

    Attributes:
        scan: (envs, points) m, the last map taken (NaN before the first); the state's array.
        stamp: (envs,) s, when it was made (-inf: none yet).
        time_since_fresh: (envs,) s, the frame's time minus ``stamp``.
        stale: (envs,) bool, ``time_since_fresh > stale_limit``, this tick's.
        maps: (envs,) int64, maps taken since the start. oldest: (envs,) s, the largest
            ``time_since_fresh`` of a tick after the first map (the run's report:
            :meth:`summary`).
    """

    def __init__(self, points: int, envs: int, stale_limit: float, source=None):
        self.points, self.envs, self.stale_limit, self.source = points, envs, stale_limit, source
        self.scan = np.full((envs, points), np.nan)
        self.stamp = np.full(envs, -np.inf)
        self.time_since_fresh = np.full(envs, np.inf)
        self.stale = np.zeros(envs, dtype=bool)
        self._fresh = np.zeros(envs, dtype=bool)
        self.maps = np.zeros(envs, dtype=np.int64)
        self.oldest = np.zeros(envs)

    def update(self, frame) -> np.ndarray:
        """Take the frame's map where it is newer than the last; returns :attr:`stale`.

        Raises:
            ValueError: a map of another shape than (envs, points).
        """
        if self.source is not None:
            self.source.fill(frame)
        scan, stamp = frame.height_scan, frame.height_scan_stamp
        if scan is not None:
            if scan.shape != self.scan.shape:
                raise ValueError(
                    f"height_scan: the map has shape {scan.shape}, the policy's scan "
                    f"{self.scan.shape} (envs, points)"
                )
            fresh = self._fresh
            np.greater(stamp, self.stamp, out=fresh)  # NaN: nothing arrived
            if fresh.any():
                self.scan[fresh] = scan[fresh]
                self.stamp[fresh] = stamp[fresh]
                self.maps += fresh
        np.subtract(frame.time, self.stamp, out=self.time_since_fresh)
        np.maximum(
            self.oldest, np.where(self.maps > 0, self.time_since_fresh, 0.0), out=self.oldest
        )
        np.greater(self.time_since_fresh, self.stale_limit, out=self.stale)
        return self.stale

    def summary(self) -> dict:
        """The run report's lines: ``points``, ``maps`` taken and ``oldest_s`` (s), per env."""
        return {
            "points": self.points,
            "stale_limit_s": self.stale_limit,
            "maps": self.maps.tolist(),
            "oldest_s": [round(float(v), 6) for v in self.oldest],
        }

    def _fields(self) -> dict:
        return {"scan": self.scan, "stamp": self.stamp, "maps": self.maps, "oldest": self.oldest}

    def state_dict(self, env: int | None = None) -> dict:
        """The last map taken, its stamp, the maps counted and the oldest seen (copies, leading
        env axis; :mod:`sim2real.deploy.core.stateful`)."""
        return take(self._fields(), env)

    def load_state_dict(self, state, env: int | None = None) -> None:
        """Raises StateDictError: a missing field or another shape (nothing written)."""
        put(self._fields(), state, env)


def height_map_stage(spec, state, envs: int, robot, backend) -> HeightMap | None:
    """The runtime's :class:`HeightMap` for a spec with a ``height_scan`` block (its scan made
    the state's ``height_scan``; the source the backend's ``height_map_source`` where it has
    one), else None."""
    block = next((b for b in spec.observation_blocks if b.name == "height_scan"), None)
    if block is None:
        return None
    limit = float(robot.stale_limit)
    stage = HeightMap(block.size, envs, limit, getattr(backend, "height_map_source", None))
    state.height_scan = stage.scan
    return stage
