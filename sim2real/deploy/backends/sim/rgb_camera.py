"""A simulated colour camera on each env of a plant (:class:`PlantRgbCamera`): the MJCF
``<camera>`` rendered by MuJoCo at its own rate and latency (the timing and the per-frame faults
of :class:`sim2real.deploy.backends.sim.plant_camera.PlantCamera`), through a CMOS sensor's model.

Each tick the frame carries the newest delivered image, ``frame.rgb_image`` (envs, rows,
columns, 3) uint8 R, G, B, and its capture time ``frame.rgb_stamp`` (envs,) s (NaN: nothing
delivered yet); the runtime's camera stage (:mod:`sim2real.deploy.runtime.camera`) reads them.

Sensor model (:class:`RgbNoise`). Noise: OmniVision's OV5647 product brief (the 5 MP sensor of
the Raspberry Pi Camera Module v1 and many UVC boards) gives a full-well capacity of 4.3 ke-, a
signal-to-noise ratio of 36 dB and a dynamic range of 68 dB. A pixel's intensity ``x`` in [0, 1]
of full scale gets Gaussian noise of variance ``x / full_well + read_noise^2``: photon shot
noise (at full scale 1 / sqrt(4300) = 1.5 %, SNR 36.3 dB, the brief's 36 dB) and a read noise
of 10^(-68/20) = 0.04 % of full scale (the dynamic range's floor). Our simplification: the noise
is applied to the rendered (display-encoded) value, not to linear light before a gamma.
Exposure and white balance drift (our choices; no datasheet gives an auto-exposure's hunting):
the image's gain is ``exp(e)`` with ``e`` an Ornstein-Uhlenbeck process of standard deviation
``exposure_drift`` (0.05: +-5 %) and time constant ``exposure_tau`` (2 s), each channel's gain
``exp(w_c)`` with ``w_c`` one of standard deviation ``white_balance_drift`` (0.03) and time
constant ``white_balance_tau`` (5 s), advanced once per captured frame. Then clipped to [0, 1]
and quantised to uint8 (``round(255 x)``), as a UVC camera's 8-bit output is.

Faults (:class:`sim2real.deploy.backends.sim.plant_camera.CameraFaults`): dropped, late and frozen
frames as the depth camera's; ``occlusion``, the fraction of the columns from the left edge
that a covered lens darkens (3 % of full scale before the noise: a finger or tape on the lens);
``extrinsic``, the MuJoCo camera's pose turned; ``lighting``, the scene's headlight and lights
scaled (:meth:`sim2real.deploy.backends.sim.rgb_render.RgbRenderer.set_lighting`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim2real.deploy.backends.sim.plant_camera import CameraFaults, PlantCamera
from sim2real.deploy.backends.sim.rgb_render import RgbRenderer
from sim2real.deploy.spec.camera import RgbImageBlock

#: OV5647 product brief: full-well capacity, electrons; SNR and dynamic range, dB.
OV5647_FULL_WELL = 4300.0
OV5647_SNR_DB = 36.0
OV5647_DYNAMIC_RANGE_DB = 68.0
#: What a covered lens reads, fraction of full scale (our choice).
COVERED = 0.03


@dataclass(frozen=True)
class RgbNoise:
    """A colour camera's sensor model (module docstring). Defaults: the OV5647's noise, our
    drifts.

    Attributes:
        full_well: Electrons at full scale (shot noise ``sqrt(x / full_well)``).
        read_noise: Read noise, fraction of full scale.
        exposure_drift, exposure_tau: The exposure's log-gain drift, standard deviation and s.
        white_balance_drift, white_balance_tau: Each channel's log-gain drift, likewise.
    """

    full_well: float = OV5647_FULL_WELL
    read_noise: float = 10 ** (-OV5647_DYNAMIC_RANGE_DB / 20)
    exposure_drift: float = 0.05
    exposure_tau: float = 2.0
    white_balance_drift: float = 0.03
    white_balance_tau: float = 5.0

    def sigma(self, x):
        """The noise's standard deviation at intensity ``x`` (fraction of full scale)."""
        return np.sqrt(np.maximum(x, 0.0) / self.full_well + self.read_noise**2)

    def snr_db(self, x: float = 1.0) -> float:
        """The signal-to-noise ratio at intensity ``x``, dB (at 1: the datasheet's SNR)."""
        return float(20 * np.log10(x / self.sigma(x)))

    def drift(self, state: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        """Advance one env's drift ``state`` (4,): exposure log-gain, then R, G, B log-gains,
        by ``dt`` s, in place (exact Ornstein-Uhlenbeck steps)."""
        for sl, sd, tau in (
            (slice(0, 1), self.exposure_drift, self.exposure_tau),
            (slice(1, 4), self.white_balance_drift, self.white_balance_tau),
        ):
            a = np.exp(-dt / tau) if tau > 0 else 0.0
            state[sl] = a * state[sl] + np.sqrt(1 - a * a) * sd * rng.standard_normal(
                sl.stop - sl.start
            )

    def apply(
        self,
        rgb: np.ndarray,
        state: np.ndarray,
        rng: np.random.Generator,
        blind: int = 0,
        normals: np.ndarray | None = None,
    ) -> np.ndarray:
        """(rows, columns, 3) uint8 rendered -> the camera's uint8, with the drift ``state``
        (4,) and the ``blind`` leftmost columns covered; ``normals``: float32 standard normal
        draws of the image's shape (default drawn from ``rng``)."""
        x = rgb.astype(np.float32)
        x *= (np.exp(state[0] + state[1:4]) / 255.0).astype(np.float32)
        if blind:
            x[:, :blind] = COVERED * np.exp(state[0] + state[1:4])
        if normals is None:
            normals = rng.standard_normal(x.shape, dtype=np.float32)
        sigma = np.maximum(x, 0.0)
        sigma *= np.float32(1.0 / self.full_well)
        sigma += np.float32(self.read_noise**2)
        np.sqrt(sigma, out=sigma)
        sigma *= normals
        x += sigma
        np.clip(x, 0.0, 1.0, out=x)
        x *= 255.0
        x += 0.5  # round half up: x >= 0
        return x.astype(np.uint8)

    def to_dict(self) -> dict:
        return asdict(self)


class PlantRgbCamera(PlantCamera):
    """The colour camera of every env of ``plant`` (module docstring).

    Args:
        plant: A simulated plant (its ``models``, ``datas``, ``envs``).
        block: The policy's RGB image block (its ``camera`` and ``shape``).
        rate: Frames per second (default the block's). latency: s (default the block's).
        noise: The sensor model (None: :class:`RgbNoise`'s defaults).
        faults: One :class:`CameraFaults` for every env or one per env (default none).
        seed: An int, or one generator per env (:class:`PlantCamera`).
        where: Named in a refusal (the robot's MJCF).

    Attributes:
        drift: (envs, 4) the exposure's and the channels' log-gains now.

    Raises:
        CameraError: the MJCF has no such camera. RuntimeError: no OpenGL context.
    """

    image_field = "rgb_image"
    stamp_field = "rgb_stamp"
    dtype = np.uint8

    def __init__(
        self,
        plant,
        block: RgbImageBlock,
        rate: float | None = None,
        latency: float | None = None,
        noise: RgbNoise | None = None,
        faults: CameraFaults | None = None,
        seed=0,
        where: str = "MJCF",
        scene=None,
    ):
        self.noise = RgbNoise() if noise is None else noise
        super().__init__(plant, block, rate, latency, faults, seed, where, RgbRenderer, scene)
        for r, f in zip(self.renderers, self.env_faults, strict=True):
            if f.lighting != 1.0:
                r.set_lighting(f.lighting)
        self.drift = np.zeros((plant.envs, 4))
        self._truth = np.zeros(block.frame_shape, np.uint8)
        #: per env, a pool of standard normal draws, twice a frame's size, made at its first
        #: frame: each frame reads a window of it at an offset drawn from the env's generator
        #: (one draw a frame instead of one per pixel: a 640 x 480 frame's 0.9 M normals cost
        #: more than its render on this machine; the windows overlap, a frame's noise is no
        #: copy of another's unless two offsets are equal)
        self._pool: list[np.ndarray | None] = [None] * plant.envs
        #: per env, the seed of its pool, drawn at construction (a camera loaded from a state
        #: dict makes the same pool)
        self._pool_seed = np.array([int(rng.integers(2**62)) for rng in self.rngs], np.int64)

    def true_image(self, env: int = 0) -> np.ndarray:
        """(rows, columns, 3) uint8, the rendered image of env ``env`` now (no sensor model)."""
        return self.renderers[env].render(self.scene_data(env), self._truth)

    def _sense(self, e: int, rng: np.random.Generator) -> np.ndarray:
        return self.sensor(e, self.true_image(e), rng)

    def sensor(self, e: int, rendered: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Env ``e``'s sensor model on a rendered (rows, columns, 3) uint8 image, as a frame
        captures it: the drift advanced one frame, the noise from the env's pool (made at its
        first frame), the covered columns; uint8 (rows, columns, 3)."""
        self.noise.drift(self.drift[e], 1.0 / self.rate, rng)
        size = int(np.prod(self.block.frame_shape))
        if self._pool[e] is None:
            pool_rng = np.random.default_rng(int(self._pool_seed[e]))
            self._pool[e] = pool_rng.standard_normal(2 * size, dtype=np.float32)
        start = int(rng.integers(size))
        normals = self._pool[e][start : start + size].reshape(self.block.frame_shape)
        return self.noise.apply(rendered, self.drift[e], rng, self._blind[e], normals)

    def _fields(self) -> dict:
        return {**super()._fields(), "drift": self.drift, "pool_seed": self._pool_seed}

    def load_state_dict(self, state, env: int | None = None) -> None:
        """:meth:`PlantCamera.load_state_dict`, the drift and the pools' seeds with it."""
        super().load_state_dict(state, env)
        self._pool = [None] * self.plant.envs  # remade from the seeds loaded

    def summary(self, env: int | None = None) -> dict:
        """:meth:`PlantCamera.summary` plus the sensor model."""
        return {**super().summary(env), "noise": self.noise.to_dict()}
