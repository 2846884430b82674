"""The plant's motors fitted to a robot's log (:func:`fit_motors`): the values that make the
replay of the log's commands (:mod:`sim2real.eval.sysid.replay`) read what the robot read.

Per motor model (the joints that share one are fitted together): dry friction (N m), viscous
damping (N m s/rad, on request), the reflected rotor inertia (armature, kg m^2) and, for a
motor with a torque-speed line, its no-load speed (rad/s); and one command delay for the robot
(s, whole physics steps). The continuous values are fitted by SciPy's bounded least squares
(``scipy.optimize.least_squares``, trust-region reflective, finite-difference Jacobian,
``soft_l1`` loss past ``ROBUST_SCALE``) on the readings' errors. The delay trades off against
the inertia, so each delay gets its own fit: a short one (``COARSE_EVALUATIONS``) at every delay
up to ``max_delay``, then a full one (``MAX_EVALUATIONS``, from the short one's values) for the
``REFINE`` delays either side of the best short fit; the best full fit is kept. The
uncertainty of each value is the standard deviation from the Jacobian at the solution
(``inv(J^T J)`` times the residual variance). The result is a plant motors file
(:mod:`sim2real.robots.plant_motors`) whose ``source`` names the log, the date, the residual and the
uncertainties.
"""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from sim2real.eval.sysid.replay import check_log, reading_errors, replay
from sim2real.robots.plant_motors import PlantMotors

#: s, the longest command delay searched (a drive's and its link's; EtherCAT and DDS links are
#: a few ms, a serial bus at 1 Mbit/s ~1 ms per packet).
MAX_DELAY = 0.03
#: Replays per delay's fit (each a few tens of ms for 1,000 ticks of a 6-joint arm).
MAX_EVALUATIONS = 30
#: Evaluations (SciPy's ``max_nfev``; each Jacobian replays once more per parameter) of a
#: delay's short fit, the pass over every delay that picks where to fit in full: on a 7 s
#: SO-101 log three already put the least cost at the true delay, rising either side.
COARSE_EVALUATIONS = 3
#: Delays (physics steps) either side of the best short fit that get a full fit.
REFINE = 2
#: rad, the readings' error past which the fit's loss grows linearly, not quadratically (SciPy's
#: ``soft_l1``): two counts of a 4096-count encoder (1.53 mrad each, the SO-101's). On a wire a
#: reading sampled a period off its stamp, or a command landing a period late, errs by tens of
#: mrad on a fast joint; squared, those few readings pulled an excitation's friction 20 % high.
ROBUST_SCALE = 3e-3


@dataclasses.dataclass
class MotorFit:
    """The fit of one motor model: ``name``, its ``joints`` (indices), the fitted ``values``
    and their standard deviations ``sigma`` by parameter (``friction`` N m, ``damping``
    N m s/rad, ``armature`` kg m^2, ``max_velocity`` rad/s when the motor has a line)."""

    name: str
    joints: list[int]
    values: dict[str, float]
    sigma: dict[str, float]


@dataclasses.dataclass
class SysidResult:
    """What :func:`fit_motors` found: ``motors`` (one :class:`MotorFit` per model), the
    ``command_delay`` (s), the readings' RMS error (rad) on the described motors
    (``rms_described``) and on the fitted ones (``rms_fitted``), and ``ticks`` fitted."""

    motors: list[MotorFit]
    command_delay: float
    rms_described: float
    rms_fitted: float
    ticks: int

    def to_toml(self, log: str) -> str:
        """The fit as a plant motors file (:mod:`sim2real.robots.plant_motors`)."""
        day = datetime.date.today().isoformat()
        parts = "; ".join(
            f"{m.name}: "
            + ", ".join(f"{k} {v:.6g} +- {m.sigma[k]:.2g}" for k, v in m.values.items())
            for m in self.motors
        )
        lines = [
            f'source = "sysid fit of {log} ({self.ticks} ticks) on {day}: readings '
            f"{1e3 * self.rms_fitted:.2f} mrad RMS off the replay (described motors "
            f"{1e3 * self.rms_described:.2f}); command delay {1e3 * self.command_delay:.1f} ms; "
            f'{parts}"',
        ]
        for m in self.motors:
            lines += ["", f"[motors.{m.name}]", f"command_delay = {self.command_delay:.6g}"]
            if "max_velocity" in m.values:
                lines.append(f"max_velocity = {m.values['max_velocity']:.6g}")
        return "\n".join(lines) + "\n"

    def joint_tables(self, joint_names: list[str]) -> str:
        """The fitted joint values as the file's ``[joints."NAME"]`` tables."""
        lines = []
        for m in self.motors:
            for j in m.joints:
                lines += ["", f'[joints."{joint_names[j]}"]']
                fitted = [k for k in ("friction", "armature", "damping") if k in m.values]
                lines += [f"{k} = {m.values[k]:.6g}" for k in fitted]
        return "\n".join(lines) + "\n"


class _Problem:
    """The replay as a function of the parameter vector (one block per motor model)."""

    def __init__(self, robot, meta, arrays, model, damping: bool):
        self.robot, self.meta, self.arrays = robot, meta, arrays
        self.fit_damping = damping
        self.dt = robot.control_period
        self.timestep = robot.control_period / robot.decimation
        names = sorted({j.motor for j in robot.config.joints})
        self.groups = [
            (n, [i for i, j in enumerate(robot.config.joints) if j.motor == n]) for n in names
        ]
        dofs = [model.jnt_dofadr[model.joint(n).id] for n in robot.joint_names]
        self.nominal = {
            "friction": model.dof_frictionloss[dofs].copy(),
            "damping": model.dof_damping[dofs].copy(),
            "armature": model.dof_armature[dofs].copy(),
        }

    def blocks(self) -> list[tuple[str, list[int], list[str]]]:
        """``(motor, joints, parameter names)`` per motor model."""
        out = []
        for name, joints in self.groups:
            params = ["friction", "damping", "armature"] if self.fit_damping else ["friction"]
            params += [] if self.fit_damping else ["armature"]
            if self.robot.motors[joints[0]].max_velocity is not None:
                params.append("max_velocity")
            out.append((name, joints, params))
        return out

    def start(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x0, lower, upper)``: the described values and their bounds."""
        x0, lo, hi = [], [], []
        for _name, joints, params in self.blocks():
            motor = self.robot.motors[joints[0]]
            peak = motor.peak_torque
            for p in params:
                if p == "friction":
                    v = float(self.nominal["friction"][joints].mean())
                    x0.append(v), lo.append(0.0), hi.append(0.3 * peak)
                elif p == "damping":
                    v = float(self.nominal["damping"][joints].mean())
                    x0.append(v), lo.append(0.0), hi.append(peak)
                elif p == "armature":
                    v = float(self.nominal["armature"][joints].mean())
                    x0.append(v), lo.append(0.1 * v), hi.append(10.0 * v)
                else:
                    v = float(motor.max_velocity)
                    x0.append(v), lo.append(0.5 * v), hi.append(1.5 * v)
        return np.array(x0), np.array(lo), np.array(hi)

    def plant(self, x: np.ndarray, delay: float) -> PlantMotors:
        """The plant motors of parameter vector ``x`` and command ``delay`` (s)."""
        n = self.robot.n_joints
        values, factors = np.full((n, 3), np.nan), np.ones((n, 3))
        motors = list(self.robot.motors)
        k = 0
        for _name, joints, params in self.blocks():
            update = {"command_delay": delay}
            for p in params:
                if p == "max_velocity":
                    update["max_velocity"] = float(x[k])
                else:
                    values[joints, ("friction", "armature", "damping").index(p)] = x[k]
                k += 1
            for j in joints:
                motors[j] = motors[j].model_copy(update=update)
        robot = dataclasses.replace(self.robot, motors=tuple(motors))
        return PlantMotors(Path("<fit>"), robot, values, factors)

    def errors(self, x: np.ndarray | None, delay: float) -> np.ndarray:
        """The readings' errors (rad, NaN as 0), flat, on the plant of ``x`` (None: the
        described motors with ``delay``)."""
        if x is None:
            x = self.start()[0]
        simulated = replay(self.robot, self.meta, self.arrays, self.plant(x, delay))
        return np.nan_to_num(reading_errors(self.arrays, simulated, self.dt)).ravel()


def fit_motors(
    robot, meta: dict, arrays: dict, max_delay: float = MAX_DELAY, damping: bool = False
) -> SysidResult:
    """Fit the plant's motors to the log ``(meta, arrays)`` of ``robot``
    (:func:`sim2real.deploy.observe.command_log.read_command_log`); see the module docstring.
    ``damping``: fit the viscous damping too (else it stays the description's): it trades
    against the dry friction unless the log spans a wide range of joint speeds, which a
    policy's log rarely does (two emulated SO-101 logs gave 0.0016 and 0.021 N m of friction
    for a truth of 0.02 with it, each with its own damping).

    Raises:
        ValueError: the log is of other joints or another control period.
    """
    check_log(robot, meta)
    problem = _Problem(robot, meta, arrays, robot.plant_model(meta["control_mode"]), damping)
    valid = np.isfinite(arrays["position"]).sum()
    described = replay(robot, meta, arrays)
    rms_described = float(
        np.sqrt(np.nansum(reading_errors(arrays, described, problem.dt) ** 2) / valid)
    )
    steps = int(round(max_delay / problem.timestep))
    x0, lower, upper = problem.start()
    x0 = np.clip(x0, lower, upper)

    def solve(d: int, x: np.ndarray, evaluations: int):
        delay = d * problem.timestep
        return least_squares(
            lambda v: problem.errors(v, delay),
            x,
            bounds=(lower, upper),
            x_scale=np.maximum(upper - lower, 1e-6) * 0.1,
            diff_step=1e-3,
            max_nfev=evaluations,
            loss="soft_l1",
            f_scale=ROBUST_SCALE,
        )

    # the delay trades off against the inertia: a short fit per delay, the best refined
    coarse = [solve(d, x0, COARSE_EVALUATIONS) for d in range(steps + 1)]
    centre = int(np.argmin([c.cost for c in coarse]))
    best = None
    for d in range(max(centre - REFINE, 0), min(centre + REFINE, steps) + 1):
        sol = solve(d, coarse[d].x, MAX_EVALUATIONS)
        if best is None or sol.cost < best[0].cost:
            best = (sol, d * problem.timestep)
    sol, delay = best
    m = max(int(valid) - len(sol.x), 1)
    squares = float(np.sum(sol.fun**2))  # the readings' errors, not the robust cost
    variance = squares / m
    try:
        sigma = np.sqrt(np.diag(np.linalg.inv(sol.jac.T @ sol.jac)) * variance)
    except np.linalg.LinAlgError:
        sigma = np.full(len(sol.x), np.inf)
    fits, k = [], 0
    for name, joints, params in problem.blocks():
        values = {p: float(sol.x[k + i]) for i, p in enumerate(params)}
        sig = {p: float(sigma[k + i]) for i, p in enumerate(params)}
        fits.append(MotorFit(name, joints, values, sig))
        k += len(params)
    return SysidResult(
        fits, delay, rms_described, float(np.sqrt(squares / valid)), len(arrays["t"])
    )
