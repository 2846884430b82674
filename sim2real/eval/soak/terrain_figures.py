"""What a legged robot did on its session's terrain tiles, tick by tick, from the plant's truth.

:class:`TerrainFigures` is a stage of a soak batch on terrain (:class:`sim2real.eval.soak.batch.
SessionBatch`). After every tick it places each env's true base (the plant's truth, x and y) on
its session's tiles (:class:`sim2real.eval.world.tile_parts.TileLayout`: the tile, and on it the
central ``platform``, the ``feature`` around it, or ``off`` the tiles) and accounts, per env:

- ``platform_s``, ``feature_s``, ``off_s``: s RUNNING on each part (a robot lying after a fall,
  or standing up, is on none);
- ``feature_m``: m, the base's horizontal path on the feature while RUNNING (its true world
  velocity's planar norm integrated);
- crossings. A **crossing out** of a tile: the base, having been on the tile's platform, leaves the
  tile (reaches its rim: another tile or the flat border), walking; a **crossing in**: having
  come onto the tile from its rim, the base reaches its platform, walking. Going onto the feature
  and back to the same platform, or back out over the same rim, crosses nothing. While not
  RUNNING (a fall, an operator's stand-up that puts the robot back at the start) the base's place
  is followed but no crossing is counted, and where an operator puts a robot down (a stand-up, a
  curriculum walk's respawn: :meth:`TerrainFigures.carried`) it is anchored anew. On
  ``stairs_down`` a crossing out goes down the steps,
  one in goes up them (``stairs_up`` and ``slope_up`` the other way round);
- falls where they happened: each of the tracker's falls (:class:`sim2real.deploy.tasks.locomotion.
  CommandTracker` ``falls``, counted at the stop) placed on the part under the base at that tick
  (``falls_on``), and listed (``fall_places``: ``t_s``, ``tile`` as ``[di, dj]`` from the start
  tile or None off the tiles, ``part``). A push fall on a stairs tile's platform is a platform fall.

A tick is one compiled call over the envs (:mod:`sim2real.eval.soak.terrain_figures_kernel`), the
truth read into a buffer of its own (its cost: docs/measurements.md). The figures are part of a
session's checkpoint (:meth:`state_dict`).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.core.stateful import env_list, put, read_records, records_json, take
from sim2real.eval.soak.terrain_figures_kernel import account
from sim2real.eval.world.tile_parts import PARTS, TileLayout, place

#: What a crossing is, for the report's readers (module docstring).
CROSSING = (
    "out: from the tile's platform to its rim (the tile left), walking; in: from its rim to its "
    "platform, walking"
)


class TerrainFigures:
    """The terrain figures of ``len(layouts)`` envs (module docstring).

    Args:
        layouts: Each env's :class:`~sim2real.eval.world.tile_parts.TileLayout` (one ranges for
            the batch: the same grid, each its own kind).
        control_period: s per tick.

    Raises:
        ValueError: layouts of different grids.
    """

    def __init__(self, layouts: list[TileLayout], control_period: float):
        self.layouts, self.dt = list(layouts), float(control_period)
        k = self.envs = len(layouts)
        first = layouts[0]
        if any(x.grid != first.grid for x in layouts[1:]):
            raise ValueError("TerrainFigures: the envs' tiles must share one grid (one ranges)")
        self._platform = np.stack([x.platform for x in layouts])  # (envs, n, n)
        self._origins = np.array([x.origin for x in layouts], dtype=np.float64)  # (envs, 2)
        self._sums = np.zeros((k, 4))  # s on the platform, the feature, off; m on the feature
        self.platform_s, self.feature_s = self._sums[:, 0], self._sums[:, 1]
        self.off_s, self.feature_m = self._sums[:, 2], self._sums[:, 3]
        self.crossings = np.zeros((k, 2), dtype=np.int64)  # out, in
        self.falls_on = np.zeros((k, len(PARTS)), dtype=np.int64)
        self.falls_seen = np.zeros(k, dtype=np.int64)
        self.anchor_tile = np.array([x.start_tile for x in layouts], dtype=np.int64)
        self.anchor_platform = np.ones(k, dtype=bool)  # the start: on the platform
        self.fall_places: list[list[dict]] = [[] for _ in range(k)]
        self._fell_tile, self._fell_part = np.zeros(k, np.int64), np.zeros(k, np.int64)
        self._running = np.zeros(k, dtype=bool)
        self._truth = np.zeros((k, 13))  # the true base, read each tick (tick)
        self._call = None  # the kernel bound to a soak's arrays (__call__) ...
        self._bound_to: tuple = ()  # ... its truth and falls

    @classmethod
    def of_batch(cls, draws: list, task, control_period: float) -> TerrainFigures | None:
        """The figures of a soak batch's sessions (their draws, :func:`sim2real.eval.world.
        session_draw.sample_session`), or None: sessions without terrain, or a task without a
        tracker (``task.tracker``) to count the falls."""
        if getattr(task, "tracker", None) is None or any(d.terrain is None for d in draws):
            return None
        return cls([TileLayout.of(d.terrain) for d in draws], control_period)

    # ------------------------------------------------------------------ per tick
    def tick(self, runtime, backend, falls: np.ndarray) -> None:
        """:meth:`__call__` with the truth of ``backend`` (its ``true_base_state``, read into a
        buffer of the figures' own)."""
        self(runtime, backend.true_base_state(self._truth), falls)

    def locate(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(tile, on_platform)`` (envs,) of the envs' points ``xy`` (envs, 2) m, each on its
        own env's tiles (:func:`sim2real.eval.world.tile_parts.place`; the kernel's rule)."""
        return place(xy, self.layouts[0], self._platform, np.arange(self.envs), self._origins)

    def carried(self, envs: np.ndarray, backend) -> None:
        """The bases of ``envs`` (bool (envs,)) were put down by hand where ``backend``'s truth
        has them now (an operator's stand-up; a curriculum walk's respawn on another tile):
        anchored there, on the tile and part under them, so that the move crosses nothing (a
        restarted robot at rest may be RUNNING again at its next tick, before the figures see
        it moved)."""
        xy = backend.true_base_state(self._truth)[:, :2]
        tile, on = self.locate(xy)
        self.anchor_tile[envs] = tile[envs]
        self.anchor_platform[envs] = on[envs]

    def _arguments(self) -> tuple:
        first = self.layouts[0]
        grid = (self._origins, first.spacing, first.n, first.rows, first.cols, self.dt)
        state = (self._sums, self.crossings, self.falls_on, self.falls_seen, self.anchor_tile)
        return (self._platform, *grid, *state, self.anchor_platform, self._fell_tile)

    def __call__(self, runtime, truth: np.ndarray, falls: np.ndarray) -> None:
        """Account one tick: ``truth`` (envs, 13) float64 the true base (position m, world; its
        ``[7:9]`` the world planar velocity, m/s), ``falls`` (envs,) int64 the tracker's fall
        counts after this tick, ``runtime.mode`` who walked; ``runtime.time`` s."""
        np.equal(runtime.mode, RUNNING, out=self._running)
        if self._call is None or self._bound_to[0] is not truth or self._bound_to[1] is not falls:
            from sim2real.deploy.kernels.calls import bind

            args = (truth, self._running, falls, *self._arguments(), self._fell_part)
            self._call, self._bound_to = bind(account, *args), (truth, falls)
        if self._call():
            self._place_falls(runtime.time)

    def step(
        self,
        xy: np.ndarray,
        velocity: np.ndarray,
        running: np.ndarray,
        falls: np.ndarray,
        t: float,
    ) -> None:
        """:meth:`__call__` on its parts: ``xy`` (envs, 2) m and ``velocity`` (envs, 2) m/s,
        the true base's world position and planar velocity, ``running`` (envs,) bool,
        ``falls`` (envs,) the fall counts, ``t`` s the session time (for the fall places)."""
        truth = np.zeros((self.envs, 9))
        truth[:, :2], truth[:, 7:9] = xy, velocity
        running = np.asarray(running, dtype=bool)
        falls = np.asarray(falls, dtype=np.int64)
        if account(truth, running, falls, *self._arguments(), self._fell_part):
            self._place_falls(t)

    def _place_falls(self, t: float) -> None:
        """List the falls of this tick (the kernel's ``fell_part``, ``fell_tile``)."""
        for e in np.flatnonzero(self._fell_part >= 0):
            self.fall_places[e].append(
                {
                    "t_s": float(t),
                    "tile": self.layouts[e].offset(int(self._fell_tile[e])),
                    "part": PARTS[int(self._fell_part[e])],
                }
            )

    # ------------------------------------------------------------------ the result
    def summary(self, e: int) -> dict:
        """Env ``e``'s figures for its session's result (``locomotion.on_terrain``)."""
        return {
            "feature": self.layouts[e].feature,
            "platform_s": float(self.platform_s[e]),
            "feature_s": float(self.feature_s[e]),
            "off_s": float(self.off_s[e]),
            "feature_m": float(self.feature_m[e]),
            "crossings_out": int(self.crossings[e, 0]),
            "crossings_in": int(self.crossings[e, 1]),
            "crossing": CROSSING,
            "falls_on": {p: int(n) for p, n in zip(PARTS, self.falls_on[e], strict=True)},
            "fall_places": [dict(x) for x in self.fall_places[e]],
        }

    # ------------------------------------------------------------------ state
    def _fields(self) -> dict[str, np.ndarray]:
        return {
            "platform_s": self.platform_s,
            "feature_s": self.feature_s,
            "off_s": self.off_s,
            "feature_m": self.feature_m,
            "crossings": self.crossings,
            "falls_on": self.falls_on,
            "falls_seen": self.falls_seen,
            "anchor_tile": self.anchor_tile,
            "anchor_platform": self.anchor_platform,
        }

    def state_dict(self, env: int | None = None) -> dict:
        """The figures (copies; :mod:`sim2real.deploy.core.stateful`'s conventions): ``platform_s``,
        ``feature_s``, ``off_s`` (s), ``feature_m`` (m), ``crossings`` (envs, 2) int64 (out, in),
        ``falls_on`` (envs, 3) int64 (:data:`~sim2real.eval.world.tile_parts.PARTS`),
        ``falls_seen`` int64, ``anchor_tile`` int64, ``anchor_platform`` bool; JSON over the
        envs: ``fall_places``."""
        out: dict = take(self._fields(), env)
        return out | records_json({"fall_places": self.fall_places}, env_list(self.envs, env))

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        envs = env_list(self.envs, env)
        places = read_records(state, ("fall_places",), len(envs))["fall_places"]
        put(self._fields(), state, env)
        for e, log in zip(envs, places, strict=True):
            self.fall_places[e] = [dict(x) for x in log]
