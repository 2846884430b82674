"""The ``height_scan`` block's pattern: a grid of terrain heights around the base, as legged_gym and
Isaac Lab define it (:class:`HeightScanPattern`, a block's ``scan``).

The raw quantity (m) at each point is the sensor's height above the terrain under it,
``z_sensor - z_hit``: legged_gym's ``measured_heights`` is ``root z - 0.5 - terrain height``
(``legged_robot.py`` ``compute_observations``), clipped to [-1, 1] m and multiplied by
``obs_scales.height_measurements`` 5.0; Isaac Lab's ``height_scan`` term
(``isaaclab/envs/mdp/observations.py``) is ``sensor.data.pos_w z - ray_hits_w z - offset`` with
``offset`` 0.5, clipped (-1, 1) in the velocity task. Both are this block with ``offset`` 0.5,
``scale`` 0.2 (1 / 5; Isaac Lab's term has scale 1: ``scale`` 1) and ``clip`` 5 (1 m after the
offset; Isaac Lab: 1): ``clip((raw - offset) / scale)`` (:mod:`sim2real.deploy.spec.policy_spec`).

The points: legged_gym's ``measured_points_x`` (17: -0.8..0.8 m step 0.1) and
``measured_points_y`` (11: -0.5..0.5 m), ``torch.meshgrid(x, y)`` (``ij``: y varies fastest);
Isaac Lab's ``GridPatternCfg(resolution, size, ordering="xy")`` (x varies fastest;
``torch.arange(-size / 2, size / 2 + 1e-9, resolution)`` per axis). Alignment of the grid with the
base: ``yaw`` (legged_gym's ``quat_apply_yaw``; Isaac Lab ``ray_alignment="yaw"``, the default of
its velocity task), ``base`` (full attitude: the rays tilt with the base) or ``world``. A miss (no
terrain under a point) reads +inf, as Isaac Lab's ``ray_hits_w`` does: the clip bounds it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.robots.errors import Sim2RealError

#: legged_gym ``LeggedRobotCfg.terrain.measured_points_x`` / ``_y``, m.
LEGGED_GYM_X = tuple(round(-0.8 + 0.1 * i, 1) for i in range(17))
LEGGED_GYM_Y = tuple(round(-0.5 + 0.1 * i, 1) for i in range(11))
#: legged_gym's and Isaac Lab's offset subtracted from the sensor's height above the terrain, m.
OFFSET = 0.5
#: legged_gym ``normalization.obs_scales.height_measurements`` 5.0 as this toolkit's divisor.
SCALE = 0.2
#: legged_gym's clip of the offset heights, 1 m, after its scale 5.0.
CLIP = 5.0
#: Alignments of the grid with the base (module docstring).
ALIGNMENTS = ("yaw", "base", "world")
#: Orders of the grid's points: ``xy`` x varies fastest (Isaac Lab), ``ij`` y fastest (legged_gym).
ORDERINGS = ("xy", "ij")


class HeightScanError(Sim2RealError, ValueError):
    """A height scan is asked of a state that has none (the runtime's height map stage fills it)."""


@dataclass(frozen=True)
class HeightScanPattern:
    """Where a ``height_scan`` block measures the terrain (JSON: a block's ``scan`` object).

    Attributes:
        x, y: The grid's coordinates along the base's forward and left axes, m (the aligned
            frame; ascending as both stacks make them).
        ordering: ``xy`` (x varies fastest) or ``ij`` (y fastest); the block's entries follow it.
        alignment: ``yaw``, ``base`` or ``world`` (module docstring).
        sensor_offset: The point the heights are measured from, relative to the base origin in
            the aligned frame, m (legged_gym, Isaac Lab's ``pos_w`` of the base: 0, 0, 0).
    """

    x: tuple[float, ...] = LEGGED_GYM_X
    y: tuple[float, ...] = LEGGED_GYM_Y
    ordering: str = "ij"
    alignment: str = "yaw"
    sensor_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def grid(
        cls, resolution: float, size: tuple[float, float], ordering: str = "xy", **kw
    ) -> HeightScanPattern:
        """Isaac Lab's ``GridPatternCfg(resolution, size, ordering)`` (m): each axis
        ``arange(-size / 2, size / 2 + 1e-9, resolution)``."""
        axes = [np.arange(-s / 2.0, s / 2.0 + 1.0e-9, resolution) for s in size]
        x, y = (tuple(round(float(v), 9) for v in a) for a in axes)
        return cls(x=x, y=y, ordering=ordering, **kw)

    @property
    def count(self) -> int:
        """The points of the grid (the block's size)."""
        return len(self.x) * len(self.y)

    def points(self) -> np.ndarray:
        """(count, 2) float64 the points' x, y in the aligned frame, m, in the block's order."""
        gx, gy = np.meshgrid(
            np.asarray(self.x, float), np.asarray(self.y, float), indexing=self.ordering
        )
        return np.stack([gx.ravel(), gy.ravel()], axis=1)

    def problems(self, where: str) -> list[str]:
        """The pattern's first problem as a one-entry list naming ``where`` and the field, or []."""
        if not self.x or not self.y or not np.all(np.isfinite(self.x + self.y)):
            return [f"{where}.scan: x and y must be non-empty lists of finite m"]
        if self.ordering not in ORDERINGS:
            return [f"{where}.scan.ordering: '{self.ordering}', expected one of {ORDERINGS}"]
        if self.alignment not in ALIGNMENTS:
            return [f"{where}.scan.alignment: '{self.alignment}', expected one of {ALIGNMENTS}"]
        if len(self.sensor_offset) != 3 or not np.all(np.isfinite(self.sensor_offset)):
            return [f"{where}.scan.sensor_offset: expected 3 finite m, got {self.sensor_offset}"]
        return []

    @classmethod
    def from_dict(cls, d: dict) -> HeightScanPattern:
        """A pattern from its JSON object (lists to tuples; missing fields take the defaults)."""
        kw = {k: tuple(float(v) for v in d[k]) for k in ("x", "y", "sensor_offset") if k in d}
        kw.update({k: str(d[k]) for k in ("ordering", "alignment") if k in d})
        return cls(**kw)


def height_scan(state, goal, raw, block, vec, rot) -> None:
    """The numpy writer of ``height_scan`` (:mod:`sim2real.deploy.spec.reference`): the state's
    scan, (envs, points) m, ``z_sensor - z_hit`` (:attr:`sim2real.deploy.core.state.RobotState.
    height_scan`, filled by the runtime's height map stage)."""
    if state.height_scan is None:
        raise HeightScanError("observation: block 'height_scan' needs a state with a height scan")
    raw[:] = state.height_scan
