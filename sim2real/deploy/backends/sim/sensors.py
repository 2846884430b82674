"""Joint sensing of the MuJoCo plant: encoders and drive temperature reports.

:class:`JointSensorModel` belongs to a :class:`sim2real.deploy.backends.sim.plant.SimBackend`; it turns the
plant's true joint angles and winding temperatures into what a drive reports, into the backend's
:class:`~sim2real.deploy.core.backend.SensorFrame`.

Sensor model (defaults from the robot's ``[sensors]`` table), applied in this order:
    1. a sample of the true joint angle at the encoder's own rate,
    2. Gaussian noise (sigma ``encoder_noise_sigma``, rad),
    3. quantization to the encoder resolution (``2 pi / encoder_resolution``),
    4. dropout: each reading lost with probability ``encoder_dropout`` (per joint and reading),
    5. latency: a reading arrives ``encoder_latency_ticks`` control ticks after it was sampled.
Winding temperatures are reported as a drive reports them: the model's winding temperature rounded
to ``temperature_resolution`` and refreshed at ``temperature_rate``.

The noise and dropout draws come from the sensor stream(s) :attr:`JointSensorModel.rng`: one
``numpy.random.PCG64`` for the batch, or one generator per env (:class:`PerEnvGenerators`,
:meth:`JointSensorModel.set_streams`); a floating-base robot's IMU and contact model
(:mod:`sim2real.deploy.backends.sim.legged_sensors`) draws from the same stream(s), after the encoder.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sim2real.deploy.backends.sim.sensors_kernel import (
    encoder_read_at,
    encoder_sample,
    temperature_report,
    velocity_read_at,
)
from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.stale import context
from sim2real.deploy.core.stateful import (
    StateDictError,
    env_list,
    rng_state,
    set_rng_state,
    set_streams,
    streams_json,
    to_json,
)
from sim2real.deploy.kernels.calls import bind
from sim2real.robots import Robot


class PerEnvGenerators:
    """One numpy ``Generator`` per env in place of the batch's one sensor stream
    (:meth:`~sim2real.deploy.backends.sim.plant.SimBackend.set_sensor_streams`).

    It answers the two calls the sensor model makes (``standard_normal(out=...)`` and
    ``random(shape)``, arrays shaped (envs, n)) row by row from each env's own generator, so that
    env ``e`` sees the same numbers alone or batched.
    """

    def __init__(self, generators: Sequence[np.random.Generator]):
        self.generators = list(generators)

    def standard_normal(self, size=None, dtype=np.float64, out=None, envs=None):
        """Normal draws, row ``e`` from env ``e``'s generator; with ``envs`` (bool (envs,)) only
        those rows are drawn (the others' streams do not move)."""
        out = np.empty(size, dtype=dtype) if out is None else out
        for e, g in enumerate(self.generators):
            if envs is None or envs[e]:
                g.standard_normal(dtype=dtype, out=out[e])
        return out

    def random(self, size=None, dtype=np.float64, out=None, envs=None):
        """Uniform draws in [0, 1), as :meth:`standard_normal`."""
        out = np.empty(size, dtype=dtype) if out is None else out
        for e, g in enumerate(self.generators):
            if envs is None or envs[e]:
                g.random(dtype=dtype, out=out[e])
        return out


def draw(rng, kind: str, out: np.ndarray, envs: np.ndarray | None) -> np.ndarray:
    """``rng.<kind>(out=out)`` (``kind``: ``"standard_normal"`` or ``"random"``; ``out`` (envs,
    ...)), drawing only the rows of the envs ``envs`` (bool (envs,)) when ``rng`` is a
    :class:`PerEnvGenerators`: a reset of some envs leaves the other envs' streams where they
    were, so a session draws the same numbers alone or batched. A single stream draws every
    row."""
    if isinstance(rng, PerEnvGenerators):
        return getattr(rng, kind)(out=out, envs=envs)
    return getattr(rng, kind)(out=out)


class JointSensorModel:
    """Encoders and winding temperature reports of ``envs`` robots (module docstring).

    Args:
        robot: The robot description (its ``[sensors]`` table, control period).
        envs: Number of robots simulated in lockstep.
        frame: The backend's sensor frame, whose joint position and temperature fields this model
            fills.
        seed: Seed of the sensor noise and dropout streams (``numpy.random.PCG64``).
        max_latency_ticks: Capacity of the latency buffer; ``latency_ticks`` may be raised up to it
            at run time (fault injection).

    Attributes (per-env sensor settings; change them between ticks to inject faults):
        noise_sigma: (envs,) rad. dropout_probability: (envs,). latency_ticks: (envs,) int.
        encoder_quantum: rad, the encoder resolution. temperature_resolution: degC.
        rng: the sensor stream(s), a ``numpy.random.Generator`` or :class:`PerEnvGenerators`.

    Raises:
        ValueError: the robot's ``encoder_latency_ticks`` above ``max_latency_ticks``.

    The encoder arithmetic runs in the kernels of :mod:`sim2real.deploy.backends.sim.sensors_kernel`; their
    numpy reference is :class:`sim2real.deploy.backends.sim.reference.ReferenceJointSensorModel`.
    """

    def __init__(
        self, robot: Robot, envs: int, frame: SensorFrame, seed: int, max_latency_ticks: int
    ):
        self.envs, n = envs, robot.n_joints
        s = robot.config.sensors
        self.noise_sigma = np.full(envs, s.encoder_noise_sigma)
        self.dropout_probability = np.full(envs, s.encoder_dropout)
        self.latency_ticks = np.full(envs, s.encoder_latency_ticks, dtype=np.int64)
        if s.encoder_latency_ticks > max_latency_ticks:
            raise ValueError(
                f"encoder_latency_ticks = {s.encoder_latency_ticks} exceeds max_latency_ticks = "
                f"{max_latency_ticks}"
            )
        self.max_latency_ticks = max_latency_ticks
        self.encoder_quantum = 2.0 * np.pi / s.encoder_resolution
        self._control_period = robot.control_period
        rate = 1.0 / robot.control_period
        self._encoder_every = max(1, int(round(rate / s.encoder_rate)))
        self._temperature_every = max(1, int(round(rate / s.temperature_rate)))
        self.temperature_resolution = s.temperature_resolution
        self.rng = np.random.Generator(np.random.PCG64(seed))
        size = max_latency_ticks + 1
        self._buf_position = np.full((size, envs, n), np.nan)
        #: the drives report a joint velocity (``[sensors] velocity_noise_sigma`` set)
        self.has_velocity = s.velocity_noise_sigma is not None
        self.velocity_noise_sigma = np.full(envs, s.velocity_noise_sigma or 0.0)
        self._buf_velocity = np.full((size, envs, n), np.nan)
        self._buf_stamp = np.full((size, envs), np.nan)
        self._env_index = np.arange(envs)
        self._uniform = np.zeros((envs, n))
        self.frame = frame
        #: (envs, n) rad, each encoder's constant offset (a calibration error: mjlab's
        #: ``randomize_encoder_bias``), added to the angle it reads; write in place
        self.encoder_bias = np.zeros((envs, n))
        self._biased = np.zeros((envs, n))
        # each slot's rows, built once (the compiled step's draws go straight into them)
        self._slots = [(self._buf_position[i], self._buf_velocity[i]) for i in range(size)]
        # the temperature report's kernel, bound to the winding temperatures of the last report
        self._reported = self._report = None
        # its kernel compiled (or loaded from numba's cache) now, not in a tick
        temperature_report(np.zeros((envs, n)), np.zeros((envs, n)), np.zeros(envs), 1.0, 0.0)
        self._bind_read()  # read's kernel, bound to latency_ticks (compiled now)

    def stale_context(self, env: int = 0, engine: str = "mujoco") -> dict:
        """What the plant's encoders of env ``env`` do now (:mod:`sim2real.deploy.core.stale`):
        the ``engine``, their rate, dropout probability and latency (ticks); ``other_side`` says
        ``every encoder reading lost`` at a dropout probability of 1, else None (the runtime's
        frame tells). Arrivals are not counted (the plant's read counts nothing)."""
        p, k = float(self.dropout_probability[env]), int(self.latency_ticks[env])
        rate = 1.0 / (self._control_period * self._encoder_every)
        return context(
            "sim",
            "encoders",
            f"the sim plant's encoders ({engine}, simulated time, {rate:g} Hz)",
            other_side=f"every encoder reading lost: dropout probability {p:g}" if p >= 1 else None,
            dropout_probability=p,
            latency_ticks=k,
        )

    @property
    def encoder_every(self) -> int:
        """Control ticks between two encoder samples (``control rate / encoder_rate``)."""
        return self._encoder_every

    @property
    def temperature_every(self) -> int:
        """Control ticks between two temperature reports (``control rate / temperature_rate``)."""
        return self._temperature_every

    def kernel_arrays(self) -> dict[str, np.ndarray]:
        """The model's live arrays, by name, for a compiled step that keeps their addresses
        (:class:`sim2real.deploy.backends.sim.compiled_step.CompiledStep`): the arrays themselves,
        not copies, float64 and C-contiguous, never rebound.

        The latency buffers, by slot (``tick % slots``, slots = ``max_latency_ticks + 1``):
        ``buffer_position`` (slots, envs, n) rad, ``buffer_velocity`` (slots, envs, n) rad/s and
        ``buffer_stamp`` (slots, envs) s; ``uniform`` (envs, n), the dropout draws of the last
        sample; ``biased`` (envs, n) rad, scratch for the biased angles; the settings
        ``noise_sigma`` (envs,) rad, ``dropout_probability`` (envs,), ``velocity_noise_sigma``
        (envs,) rad/s and ``encoder_bias`` (envs, n) rad. Raises nothing.
        """
        return {
            "buffer_position": self._buf_position,
            "buffer_velocity": self._buf_velocity,
            "buffer_stamp": self._buf_stamp,
            "uniform": self._uniform,
            "biased": self._biased,
            "noise_sigma": self.noise_sigma,
            "dropout_probability": self.dropout_probability,
            "velocity_noise_sigma": self.velocity_noise_sigma,
            "encoder_bias": self.encoder_bias,
        }

    def set_streams(self, generators: Sequence[np.random.Generator]) -> None:
        """One generator per env in place of the batch's one stream
        (:meth:`sim2real.deploy.backends.sim.plant.SimBackend.set_sensor_streams`).

        Raises:
            ValueError: not one generator per env.
        """
        if len(generators) != self.envs:
            raise ValueError(
                f"generators: expected {self.envs} (one per env), got {len(generators)}"
            )
        self.rng = PerEnvGenerators(generators)

    # ------------------------------------------------------------------ lifecycle
    def clear(self) -> None:
        """Forget every reading (the backend's clock restarts): the latency buffers and the
        temperature stamps."""
        self._buf_position.fill(np.nan)
        self._buf_velocity.fill(np.nan)
        self._buf_stamp.fill(np.nan)
        self.frame.temperature_stamp.fill(np.nan)

    def restart(self, which: np.ndarray, q: np.ndarray, time: float, ambient: np.ndarray) -> None:
        """The envs ``which`` (bool (envs,)) restart at rest at ``q`` (rad, (restarting envs, n))
        at ``time`` (s): their sensor history reads the pose, quantized, and their drives report
        the ambient temperature ``ambient`` (degC, (envs, n))."""
        quantized = np.round((q + self.encoder_bias[which]) / self.encoder_quantum)
        quantized *= self.encoder_quantum
        self._buf_position[:, which] = quantized
        self._buf_velocity[:, which] = 0.0 if self.has_velocity else np.nan
        self._buf_stamp[:, which] = time
        res = self.temperature_resolution
        self.frame.winding_temperature[which] = np.round(ambient[which] / res) * res

    # ------------------------------------------------------------------ per tick
    def sample(
        self,
        tick: int,
        time: float,
        q: np.ndarray,
        winding_temperature: np.ndarray,
        dq: np.ndarray | None = None,
    ) -> None:
        """Take the readings due at control tick ``tick`` (s ``time``): the joint angles ``q``
        (envs, n) rad into the latency buffer every ``encoder_every`` ticks (and, where the drives
        report one, the joint velocity ``dq`` (envs, n) rad/s with white noise, NaN where the
        angle dropped out), the winding temperatures (envs, n) degC into the frame at the
        temperature rate.

        The draws come from :attr:`rng` (the velocity's after the angle's); the angle's
        arithmetic is :meth:`_encode`."""
        slot = tick % self._buf_stamp.shape[0]
        if tick % self._encoder_every == 0:
            sample = self._buf_position[slot]
            self.rng.standard_normal(out=sample)
            self.rng.random(out=self._uniform)
            if self.encoder_bias.any():  # a calibration error: the encoder reads q + bias
                q = np.add(q, self.encoder_bias, out=self._biased)
            self._encode(sample, q)
            self._buf_stamp[slot] = time
            if self.has_velocity and dq is not None:
                velocity = self._buf_velocity[slot]
                self.rng.standard_normal(out=velocity)
                velocity *= self.velocity_noise_sigma[:, None]
                velocity += dq
                velocity[np.isnan(sample)] = np.nan
        else:
            self._buf_position[slot] = np.nan
            self._buf_velocity[slot] = np.nan
            self._buf_stamp[slot] = np.nan
        if tick % self._temperature_every == 0:
            self._sample_temperature(time, winding_temperature)

    def draw(self, tick: int) -> None:
        """The random draws of the encoder sample at control tick ``tick`` (an encoder tick), in
        :meth:`sample`'s order from :attr:`rng`: standard normal into the position slot, uniform
        into ``_uniform``, standard normal into the velocity slot where the drives report one.
        The compiled step (:func:`sim2real.deploy.backends.sim.plant_kernel.after_physics`) turns
        them into the readings."""
        position, velocity = self._slots[tick % len(self._slots)]
        rng = self.rng
        rng.standard_normal(out=position)
        rng.random(out=self._uniform)
        if self.has_velocity:
            rng.standard_normal(out=velocity)

    def report_temperature(self, time: float, winding_temperature: np.ndarray) -> None:
        """The drives' temperature report at ``time`` (s): ``winding_temperature`` (envs, n)
        degC rounded to :attr:`temperature_resolution` into the frame, stamped ``time``."""
        self._sample_temperature(time, winding_temperature)

    def _encode(self, sample: np.ndarray, q: np.ndarray) -> None:
        """In place: the standard normal draws ``sample`` (envs, n) become the readings of ``q``
        (envs, n) rad (noise, quantization, dropout by the uniform draws ``_uniform``): the kernel
        :func:`sim2real.deploy.backends.sim.sensors_kernel.encoder_sample`."""
        encoder_sample(
            sample,
            self._uniform,
            q,
            self.noise_sigma,
            self.encoder_quantum,
            self.dropout_probability,
        )

    def _sample_temperature(self, time: float, winding_temperature: np.ndarray) -> None:
        """The report's kernel (:func:`~sim2real.deploy.backends.sim.sensors_kernel.
        temperature_report`), bound to ``winding_temperature`` and the frame's arrays
        (:func:`~sim2real.deploy.kernels.calls.bind`): the plant passes the same array each tick."""
        if winding_temperature is not self._reported:
            f = self.frame
            args = (winding_temperature, f.winding_temperature, f.temperature_stamp)
            self._report = bind(temperature_report, *args, rest=(0.0, 0.0))
            self._reported = winding_temperature
        self._report(self.temperature_resolution, time)

    def _bind_read(self) -> None:
        """:meth:`read`'s kernel bound to the latencies, the buffers and the frame's arrays."""
        f = self.frame
        args = (self.latency_ticks, self._buf_position, self._buf_stamp, f.position)
        self._encoder_read = bind(encoder_read_at, *args, f.position_stamp, rest=(0,))
        self._velocity_read = None
        if self.has_velocity:
            velocity = (self.latency_ticks, self._buf_velocity, f.velocity)
            self._velocity_read = bind(velocity_read_at, *velocity, rest=(0,))
        self._read_key = self.latency_ticks

    def read(self, tick: int) -> None:
        """Fill the frame's joint position fields with the readings arriving at ``tick``
        (the kernel :func:`sim2real.deploy.backends.sim.sensors_kernel.encoder_read`), and the
        velocity reported with each angle read (:func:`~sim2real.deploy.backends.sim.
        sensors_kernel.velocity_read_at`)."""
        if self.latency_ticks is not self._read_key:  # bound to the present latencies
            self._bind_read()
        self._encoder_read(tick)
        if self._velocity_read is not None:
            self._velocity_read(tick)

    # ------------------------------------------------------------------ state
    def state_fields(self) -> dict[str, np.ndarray]:
        """Per-env arrays of the sensor state, env axis first (for the backend's
        ``state_dict``): settings and latency buffers (the buffers are (slots, envs, ...) inside:
        views with the env axis moved to the front)."""
        return {
            "noise_sigma": self.noise_sigma,
            "dropout_probability": self.dropout_probability,
            "latency_ticks": self.latency_ticks,
            "buffer/position": np.moveaxis(self._buf_position, 1, 0),
            "buffer/velocity": np.moveaxis(self._buf_velocity, 1, 0),
            "velocity_noise_sigma": self.velocity_noise_sigma,
            "buffer/stamp": np.moveaxis(self._buf_stamp, 1, 0),
        }

    def stream_state(self, env: int | None = None) -> str:
        """JSON of the sensor streams' ``bit_generator.state``: a list over the envs (all, or env
        ``env``) with per-env streams, the batch's one stream otherwise."""
        if isinstance(self.rng, PerEnvGenerators):
            return streams_json(self.rng.generators, env_list(self.envs, env))
        return to_json(rng_state(self.rng))

    def check_stream_state(self, rng, envs: list[int]) -> None:
        """Check that ``rng`` (the parsed JSON of :meth:`stream_state`) is of this model's kind of
        streams for the envs ``envs``.

        Raises:
            StateDictError: per-env stream states for one stream, or the reverse.
        """
        per_env = isinstance(self.rng, PerEnvGenerators)
        if per_env != (isinstance(rng, list) and len(rng) == len(envs)):
            kind = f"{len(envs)} per-env stream state(s)" if per_env else "one stream's state"
            raise StateDictError("sensor_rng", f": expected {kind}")

    def load_stream_state(self, rng, envs: list[int]) -> None:
        """Inverse of :meth:`stream_state` (parsed), checked by :meth:`check_stream_state`.

        Raises:
            StateDictError: a state of another bit generator.
        """
        if isinstance(self.rng, PerEnvGenerators):
            set_streams(self.rng.generators, envs, rng, "sensor_rng")
        else:
            set_rng_state(self.rng, rng, "sensor_rng")
