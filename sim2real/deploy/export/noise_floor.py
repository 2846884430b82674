"""The parity gate's tolerance, judged against what float32 can reach: :class:`NoiseFloor`.

ONNX Runtime and torch evaluate the same network in float32, each with its own rounding (the
order of a GEMM's sums, an LSTM kernel's activations), and how far they may differ depends on the
network: a deep or recurrent one with large activations rounds far above a small MLP. So the gate
measures it: a float64 copy of the source (:func:`float64_twin`, ``copy.deepcopy(module)
.double()``) runs on the very observations of the parity runs, and the largest ``|float32 -
float64|`` is the network's *float32 noise floor*. Each part of the gate (``PHASES``: the parity
observations or sequences, the closed-loop replay, the recurrent state; figures ``noise_floor``
and ``tolerance`` with the prefix ``''``, ``replay_``, ``state_``) is judged against the floor of
its own observations, so a regime where float32 drifts does not loosen the others::

    tolerance = max(TOLERANCE, NOISE_MULTIPLIER * noise floor)

A stateless source that cannot run in float64 (a TorchScript module whose code fixes float32,
rl_sar's RoboMimic dance) is measured on its exported graph instead, when the export gives it
(:meth:`NoiseFloor.use_graph`): the graph's own float32 answer against its float64 answer
(:mod:`sim2real.deploy.export.graph_twin`, which says why that is sound; figure
``noise_floor_of``: 'graph').

``TOLERANCE`` (absolute) is the least tolerance, and the whole tolerance when the floor cannot be
measured: the source cannot run in float64 and no graph twin was given or it does not run
either (the reason is named in the figures and messages), it is not deterministic (a second
float32 run answers differently: its noise is not rounding), or the floor is not finite or above
``UNSTABLE_FRACTION`` of the largest value compared (the network's float32 result is not stable:
a tolerance scaled on it would accept anything). ``--parity-tolerance X`` (``tolerance=`` of
:func:`sim2real.deploy.export.run_export`) sets the tolerance of actions and states to X; the floor is
still measured and reported.
"""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from sim2real.deploy.export.errors import _first_line
from sim2real.deploy.export.graph_twin import GraphTwin
from sim2real.deploy.export.recurrent import RecurrentStepper

#: The least tolerance, absolute (max abs error over all action entries).
TOLERANCE = 1e-5
#: tolerance = max(TOLERANCE, NOISE_MULTIPLIER x the float32 noise floor). Two float32
#: evaluations each within about one floor of the float64 result differ by up to twice it; 4
#: leaves another factor 2 for kernels that round differently from torch's.
NOISE_MULTIPLIER = 4.0
#: A floor above this fraction of the largest value compared (and of 1) marks a network whose
#: float32 result is not stable (float32 keeps about 7 significant digits; this is 3 left); the
#: absolute ``TOLERANCE`` applies to that part then.
UNSTABLE_FRACTION = 1e-3
#: The parts of the gate with their own floor, and the prefix of their figures.
PHASES = {"observations": "", "replay": "replay_", "state": "state_"}


def _max_abs(a: np.ndarray, b: np.ndarray) -> float:
    if a.shape != b.shape or not (np.isfinite(a).all() and np.isfinite(b).all()):
        return math.inf
    return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)), initial=0.0))


def float64_twin(module: nn.Module, recurrent: bool, obs_dim: int) -> tuple[nn.Module | None, str]:
    """A float64 copy of ``module`` that really computes in float64, or why there is none.

    Args:
        module: The export's torch module (obs -> action, or a recurrent module with explicit
            state, :class:`sim2real.deploy.export.recurrent.RecurrentPolicyModule`).
        recurrent: ``module`` takes and returns the recurrent state.
        obs_dim: Observation size (for the probe).

    Returns:
        ``(twin, "")``, or ``(None, reason)`` when the copy fails or its probe does not return
        float64 (TorchScript whose code casts to float32).
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            twin = copy.deepcopy(module).double().eval()
            obs = torch.zeros(2, obs_dim, dtype=torch.float64)
            with torch.no_grad():
                if recurrent:
                    state = [s.double() for s in module.layout.zeros(2)]
                    outputs = twin(obs, *state)
                else:
                    outputs = (twin(obs),)
    except Exception as exc:  # noqa: BLE001 - any failure: the absolute tolerance applies
        return None, f"the source cannot run in float64 ({_first_line(exc)})"
    if not all(isinstance(t, torch.Tensor) and t.dtype == torch.float64 for t in outputs):
        return None, "the source cannot run in float64 (its code computes in float32)"
    return twin, ""


@dataclass
class _Floor:
    """The largest ``|float32 - float64|`` seen, and the largest ``|float64|`` value."""

    floor: float = 0.0
    scale: float = 0.0

    def add(self, value32: np.ndarray, value64: np.ndarray) -> None:
        self.floor = max(self.floor, _max_abs(value32, value64))
        if np.isfinite(value64).all():
            self.scale = max(self.scale, float(np.max(np.abs(value64), initial=0.0)))


class FloorStepper:
    """The float32 source and its float64 twin stepped side by side on the observations of a
    recurrent parity run: ``stepper(obs)`` adds ``|action32 - action64|`` to the floor,
    ``reset(mask)`` zeroes envs on both, ``compare_states()`` adds ``|state32 - state64|``."""

    def __init__(self, floor: NoiseFloor, phase: str):
        self.floor, self.phase = floor, phase
        self.f32 = RecurrentStepper(floor.module, floor.layout, torch.float32)
        self.f64 = RecurrentStepper(floor.twin, floor.layout, torch.float64)

    def reset(self, envs: np.ndarray | None = None) -> None:
        self.f32.reset(envs)
        self.f64.reset(envs)

    def __call__(self, obs: np.ndarray, ref32: np.ndarray | None = None) -> None:
        """Step both on ``obs``; ``ref32``: the float32 source's own answer on it in the parity
        run, which this second float32 run must repeat bit for bit (else the source is not
        deterministic and has no floor)."""
        action32 = self.f32(obs)
        if ref32 is not None and not np.array_equal(action32, ref32):
            self.floor.nondeterministic = True
        self.floor.floors[self.phase].add(action32, self.f64(obs))

    def compare_states(self) -> None:
        for s32, s64 in zip(self.f32.state, self.f64.state, strict=True):
            self.floor.floors["state"].add(s32.numpy(), s64.numpy())


class NoiseFloor:
    """The float32 noise floor of a source, measured on the parity runs' own observations: the
    largest ``|float32 - float64|`` of the source module and its float64 twin.

    Args:
        module: The export's torch module. recurrent: It carries a state. obs_dim: Its input.

    Attributes:
        twin: The float64 copy, or None (``unavailable`` says why).
        floors: A :class:`_Floor` for each of ``PHASES``.
    """

    def __init__(self, module: nn.Module, recurrent: bool, obs_dim: int):
        self.module, self.recurrent = module, recurrent
        self.layout = getattr(module, "layout", None)
        self.twin, self.unavailable = float64_twin(module, recurrent, obs_dim)
        #: the exported graph run in float32 and float64 (:meth:`use_graph`), or None
        self.graph: GraphTwin | None = None
        self.floors = {phase: _Floor() for phase in PHASES}
        #: the source answered the same observation differently twice (noise in its forward)
        self.nondeterministic = False

    def use_graph(self, model) -> None:
        """Measure the floor on ``model`` (the ONNX graph exported from the source, an
        ``onnx.ModelProto`` taking the batch the parity runs give it) when the source itself
        cannot run in float64 and keeps no state; else nothing changes. A graph that does not
        run in float64 either leaves the absolute tolerance, its reason added to the note."""
        if self.twin is not None or self.recurrent:
            return
        try:
            self.graph = GraphTwin(model)
        except ValueError as exc:
            self.unavailable = f"{self.unavailable}; {exc}"

    @property
    def measured(self) -> bool:
        return (self.twin is not None or self.graph is not None) and not self.nondeterministic

    def stateless(self, obs: np.ndarray, ref32: np.ndarray, phase: str = "observations") -> None:
        """Run the twin on ``obs`` (float32 (batch, obs_dim)) and add ``|ref32 - float64|`` to
        ``phase``'s floor (``ref32``: the float32 module's answer on ``obs``, which a second
        float32 run must repeat bit for bit, else the source is not deterministic). With a graph
        twin (:meth:`use_graph`) the graph's own ``|float32 - float64|`` is added instead."""
        if self.twin is None and self.graph is None:
            return
        with torch.no_grad():
            again = self.module(torch.from_numpy(obs)).numpy()
            if self.twin is not None:
                value32, value64 = ref32, self.twin(torch.from_numpy(obs).double()).numpy()
            else:
                value32, value64 = self.graph(obs)
        if not np.array_equal(again, ref32):
            self.nondeterministic = True
        self.floors[phase].add(value32, value64)

    def stepper(self, phase: str = "observations") -> FloorStepper | None:
        """A fresh :class:`FloorStepper` adding to ``phase``'s floor (None without a twin or for
        a stateless source)."""
        if self.twin is None or not self.recurrent:
            return None
        return FloorStepper(self, phase)

    def tolerances(self, explicit: float | None = None) -> dict:
        """The gate's tolerances and how they were reached.

        Returns:
            For each part of ``PHASES`` (the state only for a recurrent source), with its
            prefix: ``noise_floor`` (None when not measured), ``tolerance``, and
            ``tolerance_note`` when the absolute ``TOLERANCE`` applies (why); and
            ``noise_multiplier``, ``tolerance_basis``: 'explicit' (``explicit`` given),
            'relative' (the floor measured), or 'absolute' (no float64 twin); with a graph twin
            ``noise_floor_of``: 'graph' (the floor is the exported graph's, :meth:`use_graph`).
        """
        out: dict = {"noise_multiplier": NOISE_MULTIPLIER}
        basis = "explicit" if explicit is not None else "relative" if self.measured else "absolute"
        measured = self.twin is not None or self.graph is not None
        out["tolerance_basis"] = basis
        if self.twin is None and self.graph is not None:
            out["noise_floor_of"] = "graph"
        for phase, prefix in PHASES.items():
            if phase == "state" and not self.recurrent:
                continue
            f = self.floors[phase]
            out[f"{prefix}noise_floor"] = f.floor if measured else None
            if basis == "explicit":
                out[f"{prefix}tolerance"] = float(explicit)
                continue
            note = ("" if self.graph is not None else self.unavailable) or (
                "the source answers the same observation differently (not deterministic): no "
                "float32 noise floor"
                if self.nondeterministic
                else ""
            )
            if self.measured and (
                not math.isfinite(f.floor) or f.floor > UNSTABLE_FRACTION * max(1.0, f.scale)
            ):
                note = (
                    f"the float32 noise floor {_num(f.floor)} is above {UNSTABLE_FRACTION:g} of "
                    f"the largest value {_num(f.scale)}: not stable in float32"
                )
            if note:
                out[f"{prefix}tolerance"] = TOLERANCE
                out[f"{prefix}tolerance_note"] = note
            else:
                out[f"{prefix}tolerance"] = max(TOLERANCE, NOISE_MULTIPLIER * f.floor)
        return out


def _num(x: float) -> str:
    """``x`` in 3 significant digits, scientific below 1e-3 (``1.74e-04``, ``0.0219``)."""
    return f"{x:.3g}" if x == 0 or not math.isfinite(x) or abs(x) >= 1e-3 else f"{x:.2e}"


def gate_passed(figures: dict) -> bool:
    """Whether every part of the gate (:data:`PHASES`) that has a tolerance in ``figures`` kept
    its error within it."""
    return all(
        figures[f"{prefix}max_abs_error"] <= figures[f"{prefix}tolerance"]
        for prefix in PHASES.values()
        if f"{prefix}tolerance" in figures
    )


def describe_tolerance(figures: dict, what: str = "", note_said: str = "") -> str:
    """The tolerance of ``figures`` (:meth:`NoiseFloor.tolerances`) in words, e.g.
    ``tolerance 2.00e-04 = 4 x the float32 noise floor 5.00e-05`` (``what``: the part's prefix
    in ``PHASES``, '' for the parity observations); an absolute tolerance's reason is given
    unless it is ``note_said`` (said already: 'as above')."""
    tol = figures[f"{what}tolerance"]
    floor = figures.get(f"{what}noise_floor")
    basis = figures.get("tolerance_basis", "absolute")
    note = figures.get(f"{what}tolerance_note")
    k = figures.get("noise_multiplier", NOISE_MULTIPLIER)
    if basis == "explicit":
        measured = "" if floor is None else f", float32 noise floor {_num(floor)}"
        return f"tolerance {_num(tol)} from --parity-tolerance{measured}"
    if basis == "relative" and not note:
        of = " of the ONNX graph" if figures.get("noise_floor_of") == "graph" else ""
        if k * floor >= TOLERANCE:
            return f"tolerance {_num(tol)} = {k:g} x the float32 noise floor{of} {_num(floor)}"
        return (
            f"tolerance {_num(tol)}, the least: {k:g} x the float32 noise floor{of} "
            f"{_num(floor)} is below it"
        )
    note = note or "no float32 noise floor"
    return f"tolerance {_num(tol)}, absolute: {'as above' if note == note_said else note}"
