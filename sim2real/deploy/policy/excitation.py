"""An excitation run for identification (``deploy-run --excitation default|FILE``): a scripted
position trajectory in place of a policy, so that a log (``--record-commands``) shows the motors'
friction, inertia, torque-speed line and delay (``sysid``, :mod:`sim2real.eval.sysid`).

Each joint alone, the others held: a smooth move from home to the joint's centre of excitation,
a logarithmic sine chirp from ``f_start`` to ``f_end`` Hz (slow sign changes of the speed show the
dry friction; the fast end the inertia and the delay), a few steps (their smoothed ramps run the
motor at the command speed limit: its torque-speed line), back home; then every joint together
(each its own phase), then home held. The amplitude is a fraction of each joint's soft half-range
(a continuous joint's, a wheel's: of half a turn), shrunk where the chirp's peak speed or
acceleration would pass a fraction of the joint's command speed or acceleration limit, so that
the smoother passes the trajectory through undistorted; the guard still checks every command, as
for any policy.

:class:`ExcitationPolicy` has a policy's face for :class:`sim2real.deploy.runtime.Runtime`: called
once per tick with the observation, it returns the action of the trajectory's next row under the
standard spec's absolute position mapping (:meth:`PolicySpec.for_robot`); its ``reset`` starts
the trajectory again. It starts with ``hold`` s at home (RAMP_IN overrides the first ticks) and
holds home after its end.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots.continuous import sampling_bounds

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib


@dataclasses.dataclass(frozen=True)
class Excitation:
    """The excitation's settings (the keys of an excitation TOML file; defaults: our choice for a
    servo arm, about a minute for six joints).

    Attributes:
        hold: s at home at the start (RAMP_IN) and at the end.
        move: s of each smooth move between home and a centre of excitation.
        amplitude: fraction of the joint's soft half-range (``(soft_upper - soft_lower) / 2``).
        together: fraction of ``amplitude`` when every joint moves at once.
        f_start, f_end: Hz, the chirp's first and last frequency.
        chirp: s of each joint's chirp alone (0: no joint alone).
        chirp_together: s of the chirp of every joint together (0: none).
        steps: the step offsets, fractions of the amplitude about the centre.
        step_time: s each step is held.
        speed: fraction of the joint's command speed limit the chirp's peak speed stays under.
        accel: fraction of the joint's acceleration limit its peak acceleration stays under.
        joints: the joints excited alone, by name (empty: every joint).
    """

    hold: float = 1.0
    move: float = 0.6
    amplitude: float = 0.3
    together: float = 0.35
    f_start: float = 0.2
    f_end: float = 3.0
    chirp: float = 5.0
    chirp_together: float = 8.0
    steps: tuple[float, ...] = (1.0, -1.0, 0.5, -0.5, 0.0)
    step_time: float = 0.5
    speed: float = 0.6
    accel: float = 0.5
    joints: tuple[str, ...] = ()

    @classmethod
    def load(cls, source: str) -> Excitation:
        """``default`` or a TOML file of :class:`Excitation`'s keys.

        Raises:
            ValueError: an unreadable file, an unknown key, a non-positive time or frequency.
        """
        if source == "default":
            return cls()
        path = Path(source)
        try:
            data = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise ValueError(f"--excitation {source}: {exc}") from None
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"--excitation {source}: unknown keys {unknown}; known {sorted(known)}"
            )
        for key in ("steps", "joints"):
            if key in data:
                data[key] = tuple(data[key])
        out = cls(**data)
        if min(out.move, out.f_start, out.step_time) <= 0 or out.f_end < out.f_start:
            raise ValueError(f"--excitation {source}: times and frequencies must be positive")
        return out


def _chirp(ex: Excitation, length: float, dt: float, phase: float):
    """``(unit, f)``, (ticks,) each: the unit chirp of ``length`` s at period ``dt`` (``sin`` of a
    logarithmic sweep from ``ex.f_start`` to ``ex.f_end`` Hz, faded in and out over ``ex.move``
    s) and its instantaneous frequency (Hz)."""
    t = np.arange(int(round(length / dt))) * dt
    ratio = ex.f_end / ex.f_start
    if ratio > 1.0:
        f = ex.f_start * ratio ** (t / length)
        theta = 2 * np.pi * ex.f_start * length / np.log(ratio) * (ratio ** (t / length) - 1)
    else:
        f = np.full_like(t, ex.f_start)
        theta = 2 * np.pi * ex.f_start * t
    fade = np.clip(np.minimum(t, length - t) / ex.move, 0.0, 1.0)
    return np.sin(theta + phase) * (0.5 - 0.5 * np.cos(np.pi * fade)), f


def _move(a: np.ndarray, b: np.ndarray, seconds: float, dt: float) -> np.ndarray:
    """(ticks, n) a smooth (half-cosine) move from pose ``a`` to ``b`` over ``seconds``."""
    s = (np.arange(1, int(round(seconds / dt)) + 1) * dt / seconds)[:, None]
    return a + (b - a) * (0.5 - 0.5 * np.cos(np.pi * s))


def trajectory(robot, ex: Excitation) -> np.ndarray:
    """(ticks, n) rad: the excitation's position targets, one row per control tick of ``robot``
    (module docstring).

    Raises:
        ValueError: an unknown joint name in ``ex.joints``.
    """
    dt, n = robot.control_period, robot.n_joints
    home = np.asarray(robot.home, dtype=float)
    # a continuous joint (a wheel) has no range: it swings within one turn about its home
    lo, hi = sampling_bounds(robot.soft_lower, robot.soft_upper)
    amp = ex.amplitude * (hi - lo) / 2
    centre = np.clip(home, lo + amp, hi - amp)
    vmax = ex.speed * np.asarray(robot.command_velocity_limit, float)
    amax = ex.accel * np.asarray(robot.acceleration_limit, float)
    names = list(robot.joint_names)
    unknown = [j for j in ex.joints if j not in names]
    if unknown:
        raise ValueError(f"--excitation: unknown joints {unknown}; the robot's are {names}")
    alone = [names.index(j) for j in ex.joints] if ex.joints else list(range(n))
    hold = np.repeat(home[None], max(1, int(round(ex.hold / dt))), axis=0)
    rows = [hold]

    def sweep(joints, scale, length, phases):
        c = home.copy()
        c[joints] = centre[joints]
        rows.append(_move(home, c, ex.move, dt))
        block = np.repeat(c[None], int(round(length / dt)), axis=0)
        for j, phase in zip(joints, phases, strict=True):
            unit, f = _chirp(ex, length, dt, phase)
            w = 2 * np.pi * f
            a = np.minimum(np.minimum(scale * amp[j], vmax[j] / w), amax[j] / w**2)
            block[:, j] += a * unit
        rows.append(block)
        for s in ex.steps:
            step = c.copy()
            step[joints] += s * scale * amp[joints]
            rows.append(np.repeat(step[None], int(round(ex.step_time / dt)), axis=0))
        rows.append(_move(rows[-1][-1], home, ex.move, dt))

    for j in alone if ex.chirp > 0 else []:
        sweep([j], 1.0, ex.chirp, [0.0])
    if ex.chirp_together > 0:
        sweep(list(range(n)), ex.together, ex.chirp_together, 2 * np.pi * np.arange(n) / n)
    rows.append(hold)
    return np.clip(np.concatenate(rows), lo, hi)


class ExcitationPolicy:
    """The excitation as a policy of ``robot`` (module docstring): ``__call__(obs)`` with
    ``obs`` (envs, obs_dim) float32 returns (envs, n) float32 actions in ``[-1, 1]`` (every env
    the same row), ``reset(envs)`` (bool mask (envs,)) starts the trajectory again, ``spec`` is
    the standard spec (joint positions observed, absolute position actions over the soft range).

    Raises:
        ValueError: a robot not driven by position targets; see :func:`trajectory`.
    """

    def __init__(self, robot, excitation: Excitation | None = None):
        if robot.control_mode != "position":
            raise ValueError(
                f"--excitation drives position targets; {robot.name} is driven by "
                f"{robot.control_mode}"
            )
        self.excitation = excitation or Excitation()
        self.spec = PolicySpec.for_robot(robot, blocks=("joint_position",), mode="position")
        a = self.spec.action
        targets = trajectory(robot, self.excitation)
        self.actions = ((targets - np.asarray(a.offset)) / np.asarray(a.scale)).astype(np.float32)
        np.clip(self.actions, -a.clip, a.clip, out=self.actions)
        #: s, the trajectory's length
        self.duration = len(self.actions) * robot.control_period
        self.tick = 0
        self._out = np.zeros((1, robot.n_joints), dtype=np.float32)

    def reset(self, envs: np.ndarray) -> None:
        """Start the trajectory again where any env of ``envs`` starts afresh."""
        if np.asarray(envs).any():
            self.tick = 0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """(envs, n) float32, C-contiguous: the trajectory's next row for every env, in a buffer
        overwritten by the next call (as :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy`
        returns its actions: the runtime's compiled screen is bound to that one array before the
        first tick; a broadcast view, read-only with zero strides, was compiled for in the
        first tick of a wall-clock run and overran it)."""
        row = self.actions[min(self.tick, len(self.actions) - 1)]
        self.tick += 1
        if self._out.shape[0] != obs.shape[0]:
            self._out = np.zeros((obs.shape[0], row.shape[0]), dtype=np.float32)
        self._out[:] = row
        return self._out
