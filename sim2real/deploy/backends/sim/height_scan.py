"""A simulated elevation map: the height scan of each env of a :class:`~sim2real.deploy.backends.sim.
plant.SimBackend` by vertical ray casts on its MuJoCo scene (:class:`PlantHeightScanner`).

The truth (:meth:`PlantHeightScanner.true_scan`): from each point of the block's pattern
(:class:`sim2real.deploy.spec.height_scan.HeightScanPattern`), placed about the true base pose
(turned by its yaw, its full attitude or not at all), a ray is cast straight down (along the
base's -z for ``base`` alignment) from ``START_HEIGHT`` above by ``mujoco.mj_ray`` on every geom
of the scene but the robot's own (a ray that meets the robot first is cast on from below the hit):
a plane, height field, box or mesh alike. The raw value is the sensor's height above the hit
point, ``z_sensor - z_hit`` (m); a ray that meets nothing reads +inf (Isaac Lab's miss).
The training stacks read the true base pose too; a robot's elevation map is built from its own
pose estimate, whose error the ``drift`` below stands for.

What arrives (:meth:`PlantHeightScanner.fill`, the frame's ``height_scan`` and
``height_scan_stamp``), with a session's :class:`HeightScanNoise`: each point plus uniform noise
in ``[-noise, noise]`` m (legged_gym's ``noise_scales.height_measurements`` 0.1 and Isaac Lab's
``Unoise(-0.1, 0.1)`` are uniform), the whole map shifted by ``drift_rate * t`` m (an elevation
map's drift against the robot's pose), ``latency_ticks`` control ticks late (stamped when it was
cast; the map exists at the start, as if cast at the ticks before), and lost with probability
``dropout`` per tick (NaN, stamp NaN). The noise is drawn from a
generator seeded by ``seed``: ``rng.uniform(-noise, noise, (envs, points))`` once per tick.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from sim2real.deploy.core.attitude import quaternion_to_matrix
from sim2real.deploy.spec.height_scan import HeightScanPattern

#: Height above the sensor the rays start from, m (Isaac Lab's velocity task: the height
#: scanner's offset 20 m up).
START_HEIGHT = 20.0
#: How far below a hit on the robot its ray is cast on, m.
STEP_THROUGH = 1.0e-6
#: Casts per ray at most (the robot's geoms it may pass through before the terrain).
MAX_CASTS = 16


@dataclass(frozen=True)
class HeightScanNoise:
    """A session's elevation map imperfections (module docstring): ``noise`` m (uniform
    half-width), ``latency_ticks`` control ticks, ``dropout`` probability per tick,
    ``drift_rate`` m/s."""

    noise: float = 0.0
    latency_ticks: int = 0
    dropout: float = 0.0
    drift_rate: float = 0.0

    def __post_init__(self):
        if not (self.noise >= 0 and self.latency_ticks >= 0 and 0 <= self.dropout <= 1):
            raise ValueError(
                f"HeightScanNoise: noise >= 0 m, latency_ticks >= 0, dropout in [0, 1]; got {self}"
            )

    def to_dict(self) -> dict:
        return asdict(self)


def robot_geoms(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) bool: the geoms of the robot, the bodies under a free joint's body (a floating
    base); a scene without one: none."""
    free = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    roots = {int(model.body_rootid[model.jnt_bodyid[j]]) for j in free}
    return np.isin(model.body_rootid[model.geom_bodyid], list(roots))


class PlantHeightScanner:
    """The height scan of every env of ``plant`` (module docstring).

    Args:
        plant: A :class:`~sim2real.deploy.backends.sim.plant.SimBackend` of a floating-base robot
            (its ``models``, ``datas``, ``true_base_state``, ``envs``, ``control_period``).
        pattern: The block's pattern.
        noise: The session's imperfections (default none).
        seed: Seed of the noise and dropout draws.
    """

    def __init__(
        self, plant, pattern: HeightScanPattern, noise: HeightScanNoise | None = None, seed=0
    ):
        self.plant, self.pattern = plant, pattern
        self.noise = noise or HeightScanNoise()
        self.points = pattern.points()  # (P, 2) m, aligned frame
        self.rng = np.random.default_rng(seed)
        envs, count = plant.envs, pattern.count
        self._robot = [robot_geoms(m) for m in plant.models]
        self._truth = np.zeros((envs, count))
        self._base = np.zeros((envs, 13))
        lag = self.noise.latency_ticks + 1
        #: the scans cast and not yet delivered: (lag, envs, P) m and their stamps (lag, envs) s
        self._ring = np.full((lag, envs, count), np.nan)
        self._stamps = np.full((lag, envs), np.nan)
        self._ticks = 0
        self._geomid = np.zeros(1, dtype=np.int32)

    @property
    def count(self) -> int:
        return self.pattern.count

    def _starts(self, base: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rays' starts (P, 3) m, their direction (3,) and the sensor's z (m) of one env's
        true base state ``base`` (13,)."""
        p = self.pattern
        rot = quaternion_to_matrix(base[None, 3:7])[0]
        if p.alignment == "yaw":
            yaw = np.arctan2(rot[1, 0], rot[0, 0])
            c, s = np.cos(yaw), np.sin(yaw)
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        elif p.alignment == "world":
            rot = np.eye(3)
        local = np.zeros((len(self.points), 3))
        local[:, :2] = self.points
        local += p.sensor_offset
        sensor = base[:3] + rot @ np.asarray(p.sensor_offset, float)
        down = rot @ np.array([0.0, 0.0, -1.0])
        starts = base[:3] + local @ rot.T - START_HEIGHT * down
        return starts, down, sensor[2]

    def true_scan(self, out: np.ndarray | None = None) -> np.ndarray:
        """(envs, P) m, ``z_sensor - z_hit`` of each point now, from the true base pose (+inf:
        no terrain under it)."""
        out = self._truth if out is None else out
        base = self.plant.true_base_state(self._base)
        for e, (m, d) in enumerate(zip(self.plant.models, self.plant.datas, strict=True)):
            starts, down, z_sensor = self._starts(base[e])
            robot, gid = self._robot[e], self._geomid
            for i, start in enumerate(starts):
                pnt, hit = start.copy(), -np.inf
                for _ in range(MAX_CASTS):
                    dist = mujoco.mj_ray(m, d, pnt, down, None, 1, -1, gid)
                    if dist < 0:
                        break
                    if not robot[gid[0]]:
                        hit = pnt[2] + dist * down[2]
                        break
                    pnt += (dist + STEP_THROUGH) * down
                out[e, i] = z_sensor - hit
        return out

    def fill(self, frame) -> None:
        """Cast this tick's scan and write what arrives into ``frame.height_scan`` ((envs, P)
        m) and ``frame.height_scan_stamp`` ((envs,) s, when it was cast; NaN: none arrived), the
        frame's arrays made on the first call (module docstring)."""
        envs, count, n = self.plant.envs, self.count, self.noise
        if getattr(frame, "height_scan", None) is None:
            frame.height_scan = np.full((envs, count), np.nan)
            frame.height_scan_stamp = np.full(envs, np.nan)
        now = np.asarray(frame.time, dtype=float)
        slot = self._ticks % len(self._ring)
        scan = self.true_scan(self._ring[slot])
        scan += self.rng.uniform(-n.noise, n.noise, (envs, count)) if n.noise else 0.0
        scan -= n.drift_rate * now[:, None]  # the map's terrain rises by the drift
        self._stamps[slot] = now
        if self._ticks == 0:  # the map exists at the start: the ticks before held this scan
            for j in range(1, len(self._ring)):
                self._ring[-j % len(self._ring)] = scan
                self._stamps[-j % len(self._ring)] = now - j * self.plant.control_period
        self._ticks += 1
        oldest = self._ticks % len(self._ring)  # the slot written latency_ticks ticks ago
        lost = self.rng.random(envs) < n.dropout if n.dropout else np.zeros(envs, dtype=bool)
        frame.height_scan[:] = self._ring[oldest]
        frame.height_scan_stamp[:] = self._stamps[oldest]
        frame.height_scan[lost] = np.nan
        frame.height_scan_stamp[lost] = np.nan

    def state_dict(self) -> dict:
        """The scans in flight, their stamps and the ticks counted (the noise generator's state
        as ``bit_generator.state``)."""
        return {
            "ring": self._ring.copy(),
            "stamps": self._stamps.copy(),
            "ticks": self._ticks,
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, state: dict) -> None:
        self._ring[:] = state["ring"]
        self._stamps[:] = state["stamps"]
        self._ticks = int(state["ticks"])
        self.rng.bit_generator.state = state["rng"]


@dataclass(frozen=True)
class HeightScanRanges:
    """The ranges a session's :class:`HeightScanNoise` is drawn from, uniformly (integers
    inclusive): ``noise`` m (0 to legged_gym's ``noise_scales.height_measurements`` 0.1 at
    ``noise_level`` 1), ``latency_ticks`` (our choice: 0-2), ``dropout`` (our choice: 0-0.01 per
    tick), ``drift_rate`` m/s (our choice: +-2 mm/s, an elevation map's slow drift)."""

    noise: tuple[float, float] = (0.0, 0.1)
    latency_ticks: tuple[int, int] = (0, 2)
    dropout: tuple[float, float] = (0.0, 0.01)
    drift_rate: tuple[float, float] = (-0.002, 0.002)

    def sample(self, rng: np.random.Generator) -> HeightScanNoise:
        """One session's draw (four draws of ``rng``, in the fields' order)."""
        return HeightScanNoise(
            noise=float(rng.uniform(*self.noise)),
            latency_ticks=int(rng.integers(self.latency_ticks[0], self.latency_ticks[1] + 1)),
            dropout=float(rng.uniform(*self.dropout)),
            drift_rate=float(rng.uniform(*self.drift_rate)),
        )


def attach_height_scanner(
    backend, spec, noise: HeightScanNoise | None = None, seed: int = 0
) -> PlantHeightScanner | None:
    """For a simulated plant (its ``models``, ``datas``, ``true_base_state``) and a spec with a
    ``height_scan`` block: the plant's ray casts of the block's pattern made the runtime's map
    source (``backend.height_map_source``, :func:`sim2real.deploy.runtime.height_map.
    height_map_stage`) and returned; else None (a backend that is no plant: its own source)."""
    block = next((b for b in spec.observation_blocks if b.name == "height_scan"), None)
    if block is None or not all(
        hasattr(backend, a) for a in ("models", "datas", "true_base_state")
    ):
        return None
    scanner = PlantHeightScanner(backend, block.scan, noise, seed)
    backend.height_map_source = scanner
    return scanner
