"""The table of the MuJoCo plant's compiled step (:mod:`sim2real.deploy.backends.sim.plant_kernel`).

:class:`CompiledStep` packs a :class:`~sim2real.deploy.backends.sim.plant.SimBackend`'s arrays
(the drives', the thermal model's, the joint sensors', the actuators') by name into the declared
table :data:`~sim2real.deploy.backends.sim.plant_kernel.PLANT`, and each env's ``MjData``
fields' addresses into its ``views``, so the kernels take one argument in place of some
thirty. Each object hands over its live arrays through its public ``kernel_arrays()`` (the
plant's ``env_views(e)`` for an env's ``MjData``). It is built once the plant's models exist;
the plant builds it afresh when an env gets a new model (``SimBackend.set_model``).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sim2real.deploy.backends.sim import plant_kernel as k
from sim2real.deploy.backends.sim.sensors import PerEnvGenerators
from sim2real.deploy.kernels.calls import bind


def _address(a: np.ndarray, dtype) -> int:
    """The address of ``a``'s first element, checked to be C-contiguous of ``dtype``.

    Raises:
        ValueError: ``a`` is not C-contiguous or not of ``dtype`` (the kernels would misread it).
    """
    if a.dtype != dtype or not a.flags.c_contiguous:
        raise ValueError(f"compiled step: expected a C-contiguous {dtype} array, got {a.dtype}")
    return a.ctypes.data


class CompiledStep:
    """The kernels' table of ``plant`` (a :class:`~sim2real.deploy.backends.sim.plant.SimBackend`
    whose models, drives, thermal model, joint sensors and actuators are built).

    Attributes:
        table: The packed :data:`~sim2real.deploy.backends.sim.plant_kernel.PLANT` table.
        views: (envs, ``PER_ENV``) int64, each env's ``MjData`` addresses (:meth:`bind`).
        streams: (envs, 3) int64, each env's sensor stream (``plant_kernel.STREAMS``).
        rng: The joint sensors' ``rng`` the streams were taken from (:meth:`bind_streams`).
        draws: Whether the kernel draws from the streams itself (numpy ``Generator`` streams);
            else the joint sensor model draws in numpy before it.

    Raises:
        ValueError: an array that is not C-contiguous of its field's dtype and dimensions.
    """

    def __init__(self, plant):
        k.compile_kernels()
        p, js, th, act = plant, plant.joint_sensors, plant.thermal, plant.actuators
        self.plant = plant
        self.streams = np.zeros((p.envs, 3), dtype=np.int64)
        self.views = np.zeros((p.envs, k.PER_ENV), dtype=np.int64)
        self.rng, self.draws, self._bit_generators = None, False, []
        pa, ja, ta, aa = (
            p.kernel_arrays(),
            js.kernel_arrays(),
            th.kernel_arrays(),
            act.kernel_arrays(),
        )
        views = p.env_views(0)
        values = dict(
            live=True, velocity_mode=p.mode == "velocity", has_velocity=js.has_velocity,
            write_ctrl=not act.active, envelope=act.envelope.any, rows=views["ctrl"].shape[0],
            warnings=views["warnings"].shape[0], nstep=p.decimation,
            quantum=js.encoder_quantum, period=p.control_period,
            command=pa["command"], qpos=pa["qpos"], qvel=pa["qvel"], torque=pa["torque"],
            start=p.derating.start, derated=pa["derated"], hot=pa["hot"], lag=pa["lag"],
            bound=pa["windup_bound"], constants=ta["constants"], ambient=ta["ambient"],
            winding=ta["winding_temperature"], housing=ta["housing_temperature"],
            current=ta["current"], power=ta["power"], flow=ta["flow"],
            buf_position=ja["buffer_position"], buf_velocity=ja["buffer_velocity"],
            buf_stamp=ja["buffer_stamp"], uniform=ja["uniform"], noise=ja["noise_sigma"],
            dropout=ja["dropout_probability"], velocity_noise=ja["velocity_noise_sigma"],
            bias=ja["encoder_bias"], biased=ja["biased"], history=aa["history"],
            delay=aa["delay_steps"], stall=aa["stall"], no_load=aa["no_load"],
            active=act.envelope.active, limit=p.effort_limit, streams=self.streams,
            t_ref=act.envelope.t_ref, alpha=act.envelope.alpha,
            stall_coefficient=act.envelope.stall_coefficient,
            no_load_speed=act.envelope.no_load_speed, supply=aa["supply"], views=self.views,
        )  # fmt: skip
        self.table = k.PLANT.pack_or_none(**values)
        if self.table is None:
            raise ValueError(f"compiled step: {k.PLANT.mismatch(values)}")
        self._env_arrays: list[list[np.ndarray]] = [[] for _ in range(p.envs)]
        for e in range(p.envs):
            self.bind(e)
        self.bind_streams()
        self._bind_kernels()

    def _bind_kernels(self) -> None:
        """:attr:`before`, :attr:`after` and :attr:`substep`: the plant kernel's calls bound to
        :attr:`table` (:func:`~sim2real.deploy.kernels.calls.bind`), ``before(tick)``,
        ``after(tick, sample)`` and ``substep(e, tick, sub)`` as ``before_physics(table,
        tick)``, ``after_physics(table, tick, sample)`` and ``actuator_substep(table, e, tick,
        sub)``."""
        self.before = bind(k.before_physics, self.table, rest=(0,))
        self.after = bind(k.after_physics, self.table, rest=(0, 0))
        self.substep = bind(k.actuator_substep, self.table, rest=(0, 0, 0))

    def bind_streams(self) -> None:
        """Take the joint sensors' present ``rng`` (one ``numpy.random.Generator`` for the
        batch, or :class:`PerEnvGenerators`): each env's bit generator state and functions
        (``BitGenerator.ctypes``) into :attr:`streams`; :attr:`draws` False (numpy draws) for a
        stream of another kind."""
        rng = self.plant.joint_sensors.rng
        envs = self.plant.envs
        generators = rng.generators if isinstance(rng, PerEnvGenerators) else [rng] * envs
        self.rng, self.draws = rng, all(isinstance(g, np.random.Generator) for g in generators)
        self._bit_generators = []
        if not self.draws:
            self.streams[:] = 0
            return
        for e, g in enumerate(generators):
            c = g.bit_generator.ctypes  # kept: its functions and state live with it
            self._bit_generators.append(c)
            self.streams[e] = (
                c.state_address,
                ctypes.cast(c.next_uint64, ctypes.c_void_p).value,
                ctypes.cast(c.next_double, ctypes.c_void_p).value,
            )

    def __reduce__(self):
        """A copy (``copy.deepcopy``, pickle) is a stale table that names no memory:
        :func:`~sim2real.deploy.backends.sim.plant_kernel.before_physics` finds it stale and
        the copied plant builds its own at its first ``advance``."""
        return (_stale_step, ())

    def bind(self, e: int) -> None:
        """Write env ``e``'s row from the plant's present views of its ``MjData`` and model
        (``SimBackend.env_views``: ``ctrl``, the joints' qpos, qvel and ``qfrc_actuator``, the
        warning counters, ``act``, the joints' ``jnt_actfrcrange`` rows).

        Raises:
            ValueError: a view that is not C-contiguous float64 (the counters: int32, 8 bytes
                apart, the layout of ``mjWarningStat``).
        """
        v = self.plant.env_views(e)
        warnings = v["warnings"]
        if warnings.dtype != np.int32 or warnings.strides[0] != 8:
            raise ValueError("compiled step: MuJoCo's warning counters changed their layout")
        views = {
            k.CTRL: v["ctrl"], k.JQPOS: v["qpos"], k.JQVEL: v["qvel"], k.FORCE: v["force"],
            k.ACT: v["act"], k.ACTFRC: v["actfrc"],
        }  # fmt: skip
        for column, a in views.items():
            self.views[e, column] = _address(a, np.float64)
        self.views[e, k.WARN] = warnings.ctypes.data
        self._env_arrays[e] = [v["model"], v["data"], *views.values(), warnings]


def _stale_step():
    """A table that :func:`~sim2real.deploy.backends.sim.plant_kernel.before_physics` finds
    stale (not ``live``): what a copied plant holds."""
    step = CompiledStep.__new__(CompiledStep)
    step.table = k.PLANT.empty()  # not live
    step.rng, step.draws = None, False
    step._bind_kernels()
    return step
