"""The table of the MuJoCo plant's compiled step (:mod:`sim2real.deploy.backends.sim.plant_kernel`).

:class:`CompiledStep` writes the addresses of a :class:`~sim2real.deploy.backends.sim.plant.SimBackend`'s
arrays (the drives', the thermal model's, the joint sensors', the actuators') and of each env's
``MjData`` fields into one int64 array, and keeps a reference to every array it names, so the
kernels can take that one array in place of some thirty arguments. It is built once the plant's
models exist and rewrites an env's row when the env gets a new model (``SimBackend._bind``).
"""

from __future__ import annotations

import ctypes

import numpy as np

from sim2real.deploy.backends.sim import plant_kernel as k
from sim2real.deploy.backends.sim.sensors import PerEnvGenerators


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
        t[k.ENVS], t[k.N], t[k.ROWS] = p.envs, p.n_joints, p._nu // p.n_joints
        t[k.SLOTS] = js._buf_stamp.shape[0]
        t[k.FLAGS] = (
            (k.VELOCITY_MODE if p.mode == "velocity" else 0)
            | (k.HAS_VELOCITY if js.has_velocity else 0)
            | (0 if act.active else k.WRITE_CTRL)
            | (k.ENVELOPE if act.envelope.any else 0)
        )
        t[k.WARNINGS], t[k.DEPTH], t[k.NSTEP] = p._warning_count, act.history.shape[1], p.decimation
        f8, b1 = np.float64, np.bool_
        arrays = {
            k.COMMAND: (p._command, f8), k.QPOS: (p._qpos, f8), k.QVEL: (p._qvel, f8),
            k.TORQUE: (p._torque, f8), k.START: (p.derating.start, f8),
            k.DERATED: (p._derated, b1), k.HOT: (p._hot, b1), k.LAG: (p._lag, f8),
            k.BOUND: (p._windup_bound, f8), k.CONSTANTS: (th._constants, f8),
            k.AMBIENT: (th.ambient, f8), k.WINDING: (th.winding_temperature, f8),
            k.HOUSING: (th.housing_temperature, f8), k.CURRENT: (th.current, f8),
            k.POWER: (th.power, f8), k.FLOW: (th._flow, f8),
            k.BUF_POSITION: (js._buf_position, f8), k.BUF_VELOCITY: (js._buf_velocity, f8),
            k.BUF_STAMP: (js._buf_stamp, f8), k.UNIFORM: (js._uniform, f8),
            k.NOISE: (js.noise_sigma, f8), k.DROPOUT: (js.dropout_probability, f8),
            k.VELOCITY_NOISE: (js.velocity_noise_sigma, f8), k.BIAS: (js.encoder_bias, f8),
            k.BIASED: (js._biased, f8), k.SCALARS: (self.scalars, f8),
            k.HISTORY: (act.history, f8), k.DELAY: (act.delay_steps, np.int64),
            k.STALL: (act._stall, f8), k.NO_LOAD: (act._no_load, f8),
            k.ACTIVE: (act.envelope.active, b1), k.LIMIT: (p.effort_limit, f8),
            k.STREAMS: (self.streams, np.int64), k.T_REF: (act.envelope.t_ref, f8),
            k.ALPHA: (act.envelope.alpha, f8),
            k.STALL_COEFFICIENT: (act.envelope.stall_coefficient, f8),
            k.NO_LOAD_SPEED: (act.envelope.no_load_speed, f8), k.SUPPLY: (act.supply, f8),
        }  # fmt: skip
        self._arrays = [a for a, _ in arrays.values()]  # alive while the table names them
        t[k.SELF] = t.ctypes.data  # a copied table holds another array's address: stale
        for slot, (a, dtype) in arrays.items():
            t[slot] = _address(a, dtype)
        self._env_arrays: list[list[np.ndarray]] = [[] for _ in range(p.envs)]
        for e in range(p.envs):
            self.bind(e)
        self.bind_streams()

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
        (``ctrl``, the joints' qpos, qvel and ``qfrc_actuator``, the warning counters, ``act``,
        the joints' ``jnt_actfrcrange`` rows).

        Raises:
            ValueError: a view that is not C-contiguous float64 (the counters: int32, 8 bytes
                apart, the layout of ``mjWarningStat``).
        """
        p = self.plant
        m, d, ctrl, qpos, force, warnings = p._views[e]
        if warnings.dtype != np.int32 or warnings.strides[0] != 8:
            raise ValueError("compiled step: MuJoCo's warning counters changed their layout")
        row = k.ENV_ROWS + k.PER_ENV * e
        act = d.act if p.mode == "velocity" else np.zeros(0)
        views = {
            k.CTRL: ctrl, k.JQPOS: qpos, k.JQVEL: p._qvel_views[e], k.FORCE: force,
            k.ACT: act, k.ACTFRC: p._actfrc[e],
        }  # fmt: skip
        for field, a in views.items():
            self.table[row + field] = _address(a, np.float64)
        self.table[row + k.WARN] = warnings.ctypes.data
        self._env_arrays[e] = [m, d, *views.values(), warnings]


def _stale_step():
    """A table that :func:`~sim2real.deploy.backends.sim.plant_kernel.before_physics` finds
    stale (its ``SELF`` entry is not its own address): what a copied plant holds."""
    step = CompiledStep.__new__(CompiledStep)
    step.table = np.zeros(k.ENV_ROWS, dtype=np.int64)
    step.rng, step.draws = None, False
    return step
