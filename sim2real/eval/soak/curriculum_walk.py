"""A soak session on terrain walked as legged_gym's terrain curriculum walks its robots
(``[terrain] walk = "curriculum"``, :class:`sim2real.eval.world.terrain.TerrainRanges`).

legged_gym lays its terrain as a map of ``num_rows x num_cols`` tiles: row ``i`` (along x) is
level ``i`` at difficulty ``i / num_rows``, column ``j`` (along y) a kind (``Terrain.curiculum``,
legged_gym ``legged_gym/utils/terrain.py``, HIMLoco's copy ``legged_gym/legged_gym/utils/
terrain.py:85-92``). A robot spawns at the centre of its tile (``env_origins[level, type]``,
``_get_env_origins``, HIMLoco ``legged_gym/envs/base/legged_robot.py:893-907``) plus a uniform
+-1 m in x and y (``_reset_root_states``, ``legged_robot.py:529-532``), walks an episode of
``episode_length_s`` (20 s) or until it falls, and at its reset the game-inspired curriculum
moves its level (``_update_terrain_curriculum``, ``legged_robot.py:557-576``): with ``distance``
the base's planar distance from its tile's centre,

- up one level if ``distance > terrain_length / 2`` (it walked off its tile);
- else down one if ``distance < |command_xy| * episode_length_s * 0.5`` (less than half of what
  its command asked; the command in force at the reset, the episode's nominal length even when
  it fell early);
- a robot past the last level is sent to a level drawn uniformly from all; none goes below 0.

Then it is respawned on its new level's tile with a new command (``reset_idx``:
``_reset_root_states``, ``_resample_commands``).

Here a session's ground is its kind's column of levels, walked by :class:`CurriculumWalk`.

What each env did: episodes ended by a timeout and by a stop, moves up and down, its first and
last level, and per level the RUNNING seconds its base spent on that row's tiles and the
episodes that started there (:meth:`summary`); the per-tile figures are
:mod:`sim2real.eval.soak.terrain_figures`'.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.core.stateful import (
    env_list,
    put,
    read_streams,
    set_streams,
    streams_json,
    take,
)
from sim2real.eval.world.terrain import spawn_height

#: legged_gym ``_reset_root_states``: a respawn lands within this of its tile's centre, m, in x
#: and in y, uniformly (``torch_rand_float(-1., 1., ...)``).
SPAWN_SPREAD = 1.0
#: The rule in words, for the report's readers (module docstring).
RULE = (
    "legged_gym's _update_terrain_curriculum at each episode's end (timeout, or a stop: the "
    "operator's stand-up after a fall or a latched fault): up one "
    "level if the base ended over terrain_length / 2 from its tile's centre, else down one if "
    "under |command_xy| * episode_length_s / 2; past the last level a uniform level"
)
#: Why an episode ended (index into :attr:`CurriculumWalk.ended`).
ENDS = ("timeout", "stop")


class CurriculumWalk:
    """The curriculum walk of a soak batch's envs (the rule: module docstring).

    Here a session's ground is its kind's column: one tile per level along x, ``tiles`` tiles of the
    same kind along y (legged_gym's neighbouring columns hold other kinds; ours repeat the
    session's, so that one kind's figures are one kind's). The robot starts at the centre of its
    drawn level's tile (the plant's spawn, the world origin; legged_gym's first spawn is offset by
    the same +-1 m, ``_create_envs``, ``legged_robot.py:861``, ours is not).
    It counts each env's RUNNING time in its episode; at ``episode_length_s`` (a timeout) or at
    the operator's stand-up after a stop (a fall, a latched fault: legged_gym's termination) it
    applies the rule, and the stand-up
    (:meth:`sim2real.eval.soak.batch.SessionBatch.stand_up`) puts the robot at rest on the new
    level's tile centre plus the +-1 m, raised to the ground there as at the start
    (:func:`sim2real.eval.world.terrain.spawn_height`), and its command schedule draws a new
    command at once. A timeout's respawn is an operator's restart without a fault (RAMP_IN),
    counted apart from the stand-ups after falls.

    Args:
        layouts: Each env's :class:`~sim2real.eval.world.tile_parts.TileLayout` (a curriculum
            walk's: rows are levels).
        levels: Each env's first level (its draw's).
        grounds: Each env's :class:`~sim2real.eval.world.terrain.GroundMap`.
        ranges: The batch's :class:`~sim2real.eval.world.terrain.TerrainRanges`.
        control_period: s per tick.
        streams: One numpy generator per env (the respawns' +-1 m and a uniform level).

    Attributes:
        level: (envs,) int64, the current level (row). col: the column the robot respawns in.
        centre: (envs, 2) m, the current episode's tile centre (world).
        walked_s: (envs,) s RUNNING in the current episode.
        ended: (envs, 2) int64, episodes ended by a timeout and by a stop (a fall or a latched
            fault: the operator's stand-up; :data:`ENDS`).
        moves: (envs, 2) int64, moves up and down.
        level_s: (envs, num_rows) s RUNNING with the base over each row's tiles.
        started_on: (envs, num_rows) int64, episodes begun on each level.
        first_level: (envs,) int64.
    """

    def __init__(self, layouts, levels, grounds, ranges, control_period: float, streams):
        self.layouts, self.grounds, self.streams = list(layouts), list(grounds), list(streams)
        k = self.envs = len(self.layouts)
        self.rows = ranges.num_rows
        self.dt, self.episode_s = float(control_period), float(ranges.episode_length_s)
        self.half_length = ranges.terrain_length / 2
        self.col = self.layouts[0].cols // 2
        self.level = np.array(levels, dtype=np.int64)
        self.first_level = self.level.copy()
        self.centre = np.array(
            [x.centre(int(v), self.col) for x, v in zip(self.layouts, levels, strict=True)]
        )
        self.walked_s = np.zeros(k)
        self.ended = np.zeros((k, 2), dtype=np.int64)
        self.moves = np.zeros((k, 2), dtype=np.int64)
        self.level_s = np.zeros((k, self.rows))
        self.started_on = np.zeros((k, self.rows), dtype=np.int64)
        self.started_on[np.arange(k), self.level] = 1
        self._truth = np.zeros((k, 13))

    @classmethod
    def of_batch(cls, draws, figures, grounds, control_period: float, streams):
        """The walk of a soak batch (its sessions' draws, their
        :class:`~sim2real.eval.soak.terrain_figures.TerrainFigures` and grounds), or None:
        no terrain figures, or not a curriculum walk."""
        if figures is None or draws[0].terrain.ranges.walk != "curriculum":
            return None
        levels = [d.terrain.level for d in draws]
        return cls(
            figures.layouts, levels, grounds, draws[0].terrain.ranges, control_period, streams
        )

    # ------------------------------------------------------------------ per tick
    def tick(self, runtime, backend) -> np.ndarray:
        """After a tick: count the RUNNING envs' time in their episode and on their row; returns
        the envs (bool (envs,)) whose episode timed out (the caller respawns them:
        :meth:`sim2real.eval.soak.batch.SessionBatch.stand_up`)."""
        running = runtime.mode == RUNNING
        if not running.any():
            return running
        truth = backend.true_base_state(self._truth)
        self.walked_s[running] += self.dt
        for e in np.flatnonzero(running):
            x = self.layouts[e]
            u = (truth[e, :2] - x.origin) / (x.spacing * x.n)
            if 0 <= u[0] < x.rows and 0 <= u[1] < x.cols:
                self.level_s[e, int(u[0])] += self.dt
        return running & (self.walked_s >= self.episode_s - 1e-9)

    def next_level(self, e: int, xy: np.ndarray, command_xy: np.ndarray) -> tuple[int, int]:
        """``(level, move)`` after env ``e``'s episode ending with its base at world ``xy`` (2,)
        m under the command ``command_xy`` (2,) m/s: legged_gym's rule (module docstring);
        ``move`` +1, -1 or 0. Draws from the env's stream only past the last level."""
        distance = float(np.linalg.norm(np.asarray(xy) - self.centre[e]))
        up = distance > self.half_length
        down = (not up) and distance < float(np.linalg.norm(command_xy)) * self.episode_s * 0.5
        level = int(self.level[e]) + int(up) - int(down)
        if level >= self.rows:
            level = int(self.streams[e].integers(self.rows))
        return max(level, 0), int(up) - int(down)

    def end_episodes(self, envs: np.ndarray, backend, command: np.ndarray, end: str) -> np.ndarray:
        """End the episodes of ``envs`` (bool (envs,)) for ``end`` (:data:`ENDS`): move their
        levels by the rule (the true base now, ``command`` (envs, >= 2) the velocity commands in
        force), draw their respawns; returns (envs, 3) m, each env's base offset from its
        plant's spawn (zeros for the others), for ``SimBackend.reset``."""
        truth = backend.true_base_state(self._truth)
        offsets = np.zeros((self.envs, 3))
        for e in np.flatnonzero(envs):
            level, move = self.next_level(e, truth[e, :2], command[e, :2])
            self.ended[e, ENDS.index(end)] += 1
            if move:
                self.moves[e, 0 if move > 0 else 1] += 1
            self.level[e] = level
            self.started_on[e, level] += 1
            self.walked_s[e] = 0.0
            self.centre[e] = self.layouts[e].centre(level, self.col)
            xy = self.centre[e] + self.streams[e].uniform(-SPAWN_SPREAD, SPAWN_SPREAD, 2)
            g = self.grounds[e]
            offsets[e] = (*xy, spawn_height(g, *xy) - spawn_height(g))
        return offsets

    # ------------------------------------------------------------------ the result
    def summary(self, e: int) -> dict:
        """Env ``e``'s walk for its session's result (``locomotion.on_terrain.curriculum``)."""
        levels = {
            str(i): {"s": float(self.level_s[e, i]), "episodes": int(self.started_on[e, i])}
            for i in range(self.rows)
            if self.level_s[e, i] > 0 or self.started_on[e, i] > 0
        }
        episodes = int(self.ended[e].sum())
        return {
            "episode_length_s": self.episode_s,
            "episodes_ended": episodes,
            "ended_by": {k: int(v) for k, v in zip(ENDS, self.ended[e], strict=True)},
            "moved_up": int(self.moves[e, 0]),
            "moved_down": int(self.moves[e, 1]),
            "stayed": episodes - int(self.moves[e].sum()),
            "first_level": int(self.first_level[e]),
            "level": int(self.level[e]),
            "levels": levels,
            "rule": RULE,
        }

    # ------------------------------------------------------------------ state
    def _fields(self) -> dict[str, np.ndarray]:
        return {
            "level": self.level,
            "centre": self.centre,
            "walked_s": self.walked_s,
            "ended": self.ended,
            "moves": self.moves,
            "level_s": self.level_s,
            "started_on": self.started_on,
        }

    def state_dict(self, env: int | None = None) -> dict:
        """The walk (copies; :mod:`sim2real.deploy.core.stateful`'s conventions): ``level``
        int64, ``centre`` (envs, 2) m, ``walked_s`` s, ``ended`` and ``moves`` (envs, 2) int64,
        ``level_s`` (envs, num_rows) s, ``started_on`` (envs, num_rows) int64; ``rng``: JSON of
        the streams' states."""
        out: dict = take(self._fields(), env)
        out["rng"] = streams_json(self.streams, env_list(self.envs, env))
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field, a shape or a stream count that differs; nothing is
                changed.
        """
        envs = env_list(self.envs, env)
        rng = read_streams(state, "rng", len(envs))
        put(self._fields(), state, env)
        set_streams(self.streams, envs, rng, "rng")
