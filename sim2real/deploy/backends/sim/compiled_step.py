"""The table of the MuJoCo plant's compiled step (:mod:`sim2real.deploy.backends.sim.plant_kernel`).

:class:`CompiledStep` writes the addresses of a :class:`~sim2real.deploy.backends.sim.plant.SimBackend`'s
arrays (the drives', the thermal model's, the joint sensors', the actuators') and of each env's
``MjData`` fields into one int64 array, and keeps a reference to every array it names, so the
kernels can take that one array in place of some thirty arguments. Each object hands over its
live arrays through its public ``kernel_arrays()`` (the plant's ``env_views(e)`` for an env's
``MjData``). It is built once the plant's models exist; the plant builds it afresh when an env
gets a new model (``SimBackend.set_model``).
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
        table: (46 + 7 envs,) int64, the header and addresses of
            :mod:`~sim2real.deploy.backends.sim.plant_kernel`.
        scalars: (2,) float64, the encoder quantum (rad) and the control period (s).
        streams: (envs, 3) int64, each env's sensor stream (``plant_kernel.STREAMS``).
        rng: The joint sensors' ``rng`` the streams were taken from (:meth:`bind_streams`).
        draws: Whether the kernel draws from the streams itself (numpy ``Generator`` streams);
            else the joint sensor model draws in numpy before it.

    Raises:
        ValueError: an array that is not C-contiguous of the expected type.
    """

    def __init__(self, plant):
        k.compile_kernels()
        p, js, th, act = plant, plant.joint_sensors, plant.thermal, plant.actuators
        self.plant = plant
        self.scalars = np.array([js.encoder_quantum, p.control_period])
        self.table = np.zeros(k.ENV_ROWS + k.PER_ENV * p.envs, dtype=np.int64)
        self.streams = np.zeros((p.envs, 3), dtype=np.int64)
        self.rng, self.draws, self._bit_generators = None, False, []
        t = self.table
        pa, ja, ta, aa = (
            p.kernel_arrays(),
            js.kernel_arrays(),
            th.kernel_arrays(),
            act.kernel_arrays(),
        )
        views = p.env_views(0)
        t[k.ENVS], t[k.N], t[k.ROWS] = p.envs, p.n_joints, views["ctrl"].shape[0]
        t[k.SLOTS] = ja["buffer_stamp"].shape[0]
        t[k.FLAGS] = (
            (k.VELOCITY_MODE if p.mode == "velocity" else 0)
            | (k.HAS_VELOCITY if js.has_velocity else 0)
            | (0 if act.active else k.WRITE_CTRL)
            | (k.ENVELOPE if act.envelope.any else 0)
        )
        t[k.WARNINGS], t[k.DEPTH] = views["warnings"].shape[0], aa["history"].shape[1]
        t[k.NSTEP] = p.decimation
        f8, b1 = np.float64, np.bool_
        arrays = {
            k.COMMAND: (pa["command"], f8), k.QPOS: (pa["qpos"], f8), k.QVEL: (pa["qvel"], f8),
            k.TORQUE: (pa["torque"], f8), k.START: (p.derating.start, f8),
            k.DERATED: (pa["derated"], b1), k.HOT: (pa["hot"], b1), k.LAG: (pa["lag"], f8),
            k.BOUND: (pa["windup_bound"], f8), k.CONSTANTS: (ta["constants"], f8),
            k.AMBIENT: (ta["ambient"], f8), k.WINDING: (ta["winding_temperature"], f8),
            k.HOUSING: (ta["housing_temperature"], f8), k.CURRENT: (ta["current"], f8),
            k.POWER: (ta["power"], f8), k.FLOW: (ta["flow"], f8),
            k.BUF_POSITION: (ja["buffer_position"], f8),
            k.BUF_VELOCITY: (ja["buffer_velocity"], f8), k.BUF_STAMP: (ja["buffer_stamp"], f8),
            k.UNIFORM: (ja["uniform"], f8), k.NOISE: (ja["noise_sigma"], f8),
            k.DROPOUT: (ja["dropout_probability"], f8),
            k.VELOCITY_NOISE: (ja["velocity_noise_sigma"], f8), k.BIAS: (ja["encoder_bias"], f8),
            k.BIASED: (ja["biased"], f8), k.SCALARS: (self.scalars, f8),
            k.HISTORY: (aa["history"], f8), k.DELAY: (aa["delay_steps"], np.int64),
            k.STALL: (aa["stall"], f8), k.NO_LOAD: (aa["no_load"], f8),
            k.ACTIVE: (act.envelope.active, b1), k.LIMIT: (p.effort_limit, f8),
            k.STREAMS: (self.streams, np.int64), k.T_REF: (act.envelope.t_ref, f8),
            k.ALPHA: (act.envelope.alpha, f8),
            k.STALL_COEFFICIENT: (act.envelope.stall_coefficient, f8),
            k.NO_LOAD_SPEED: (act.envelope.no_load_speed, f8), k.SUPPLY: (aa["supply"], f8),
        }  # fmt: skip
        self._arrays = [a for a, _ in arrays.values()]  # alive while the table names them
        t[k.SELF] = t.ctypes.data  # a copied table holds another array's address: stale
        for slot, (a, dtype) in arrays.items():
            t[slot] = _address(a, dtype)
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
        row = k.ENV_ROWS + k.PER_ENV * e
        views = {
            k.CTRL: v["ctrl"], k.JQPOS: v["qpos"], k.JQVEL: v["qvel"], k.FORCE: v["force"],
            k.ACT: v["act"], k.ACTFRC: v["actfrc"],
        }  # fmt: skip
        for field, a in views.items():
            self.table[row + field] = _address(a, np.float64)
        self.table[row + k.WARN] = warnings.ctypes.data
        self._env_arrays[e] = [v["model"], v["data"], *views.values(), warnings]


def _stale_step():
    """A table that :func:`~sim2real.deploy.backends.sim.plant_kernel.before_physics` finds
    stale (its ``SELF`` entry is not its own address): what a copied plant holds."""
    step = CompiledStep.__new__(CompiledStep)
    step.table = np.zeros(k.ENV_ROWS, dtype=np.int64)
    step.rng, step.draws = None, False
    step._bind_kernels()
    return step
