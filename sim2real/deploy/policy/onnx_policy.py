"""OnnxPolicy: load an exported policy, verify it against the robot, run it batch-first.

The runtime's only view of a policy: an ONNX file and the robot description are enough (no
torch, no training code). Loading refuses, with :class:`~sim2real.deploy.spec.onnx_checks.PolicyLoadError`
naming the file and the problem: a missing, corrupt or unsafe file and non-finite weights
(:mod:`sim2real.deploy.spec.onnx_checks`); no spec, or one that contradicts the file's or does not match
the robot (:mod:`sim2real.deploy.policy.onnx_spec`, ``PolicySpec.check_robot``); a graph whose inputs,
outputs or recurrent state the spec does not describe (:mod:`sim2real.deploy.policy.onnx_graph`); and an
action that is not finite for the zero observation or, for a foreign file (an export's parity gate
already probed ours), for every entry at -1, at +1 and 29 uniform draws in [-1, 1].

A spec's image inputs (``images``: a depth or colour camera's frames,
:mod:`sim2real.deploy.spec.camera`) are bound arrays, :attr:`OnnxPolicy.images` (float32
``(envs, *block.input_shape)``: depth ``(envs, frames, rows, columns)``, RGB ``(envs, frames, 3,
rows, columns)`` or ``(envs, frames, rows, columns, 3)``), that the runtime's camera stage writes
before each call (zeros until then; :meth:`OnnxPolicy.bind_batch` binds them for its envs).

Observations are float32 ``(envs, obs_dim)``, actions float32 ``(envs, act_dim)`` in the spec's
``joint_names`` order (a spec's ``action.joints`` reorders the graph's outputs). A recurrent
policy keeps each env's state (``[layers, envs, hidden]`` float32), feeds ``<name>_out`` back as
``<name>_in`` on the next call, and :meth:`OnnxPolicy.reset` sets it to its initial value (zeros,
or the file's declared initial state). Inference runs single-threaded, sequential, spinning off,
through an IOBinding bound to preallocated numpy buffers, rebound only when the batch size
changes; a caller's observation array passed on consecutive calls (the runtime's) is bound as the
input itself, and the call is then the session's C++ run alone.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort

from sim2real.deploy.policy.onnx_graph import check_graph
from sim2real.deploy.policy.onnx_spec import METADATA_SPEC, resolve_spec
from sim2real.deploy.spec.onnx_checks import (
    PolicyLoadError,
    check_external_data,
    check_finite_weights,
    read_model,
)
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError
from sim2real.deploy.spec.subset import run_spec
from sim2real.robots import Robot


class OnnxPolicy:
    """An exported policy, verified against a robot, run with ONNX Runtime.

    Args:
        path: The ``.onnx`` file.
        robot: The robot it will drive; the spec is checked against it.
        spec: Optional PolicySpec (or a spec JSON file). Required for a foreign ONNX file without
            ``policy_spec`` metadata; otherwise it must agree with the stored spec (``baked`` and
            ``parity`` aside).
        check_hash: Also compare the robot description hash (default True).

    Attributes:
        path: The file. spec: The PolicySpec in force. metadata: The file's custom metadata
            (``str -> str``; ``policy_spec``, ``parity``, ``tool_versions`` hold JSON).
        foreign: The :class:`~sim2real.deploy.spec.foreign.ForeignContract` the spec was built from, or
            None (our metadata or a given spec).
        input_name, output_name: Graph input and output used. obs_dim, act_dim: Sizes.
        states: The recurrent states (:class:`~sim2real.deploy.policy.onnx_graph.StateTensor`; empty for
            a feed-forward policy).
        recurrent: Whether there are any. session: The ``onnxruntime.InferenceSession``.

    Raises:
        PolicyLoadError: see the module docstring.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        robot: Robot,
        spec: PolicySpec | str | os.PathLike | None = None,
        check_hash: bool = True,
    ):
        self.path = path = Path(path)
        model = _checked_model(path)
        self.metadata: dict[str, str] = {p.key: p.value for p in model.metadata_props}
        #: The training stack's own contract the spec was built from (None: ours or --spec).
        self.spec, self.foreign = resolve_spec(path, spec, model, robot, self.metadata)
        try:
            #: the joints of the policy's own spec (a policy over some of the robot's joints)
            self.policy_joints = tuple(self.spec.joint_names)
            self.spec = run_spec(self.spec, robot)  # a policy over part of it: the rest held
            self.spec.check_robot(robot, check_hash=check_hash)
        except SpecError as exc:  # name the spec file the user gave, else the ONNX file
            where = spec if isinstance(spec, str | os.PathLike) else path
            raise PolicyLoadError(f"{where}: {exc}") from None
        self.obs_dim, self.act_dim = self.spec.obs_dim, self.spec.act_dim
        (
            self.input_name,
            self.output_name,
            self._fixed_batch,
            self.states,
            self._constant_specs,
        ) = check_graph(model, path, self.spec)
        self.recurrent = bool(self.states)
        joints = self.spec.action.joints
        #: graph output i drives spec-order joint _joints[i] (None: the same order)
        self._joints = None if not joints else np.asarray(joints, dtype=np.intp)

        self.session = _session(model, path)
        self._binding = self.session.io_binding()
        self._run = self._runner()
        #: after the graph ran: the scatter into joint order and the recurrent states' copy
        #: (None: nothing to do, a feed-forward policy in the spec's joint order)
        self._finish = None if (self._joints is None and not self.states) else self._finish_call
        self._batch = -1
        self.images: dict[str, np.ndarray] = {}
        #: the array bound as the graph's input: ``_obs`` (a caller's observation copied in) or
        #: the caller's own array, read in place (:meth:`__call__`); and the last one seen
        self._input = self._seen = None
        self._obs = np.zeros((0, self.obs_dim), np.float32)
        self._action = np.zeros((0, self.act_dim), np.float32)
        #: recurrent: (state input buffer, state output buffer) per state, (layers, batch, hidden)
        self._state_pairs: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
        probe_batch = self._fixed_batch or 1
        if self.recurrent:  # batch 2 too: a state output may ignore the batch axis
            for batch in (probe_batch,) if self._fixed_batch else (1, 2):
                self._check_state_shapes(path, batch)
        try:
            probe = self(np.zeros((probe_batch, self.obs_dim), np.float32))
        except Exception as exc:  # noqa: BLE001
            raise PolicyLoadError(
                f"{path}: running the model on a zero observation of shape "
                f"({probe_batch}, {self.obs_dim}) failed: {exc}"
            ) from None
        if not np.isfinite(probe).all():
            raise PolicyLoadError(f"{path}: the action for the zero observation is not finite")
        if METADATA_SPEC not in self.metadata:  # an export's parity gate probed it already
            self._probe_range(path, probe_batch)
        self.reset()  # the probe advanced the state

    # ------------------------------------------------------------------ load probes
    def _probe_range(self, path: Path, batch: int) -> None:
        """Judge the model by its answers: the action must be finite for every entry at -1 and at
        +1 and for 29 uniform draws in [-1, 1] (seed 0): the range the spec's normalized
        observations live in. Each probe starts from the initial recurrent state."""
        rows = np.random.default_rng(0).uniform(-1.0, 1.0, (31, self.obs_dim)).astype(np.float32)
        rows[0], rows[1] = 1.0, -1.0
        for k, row in enumerate(rows):
            self.reset()
            action = self(np.broadcast_to(row, (batch, self.obs_dim)))
            if not np.isfinite(action).all():
                what = (
                    ("every entry at +1", "every entry at -1")[k]
                    if k < 2
                    else (f"uniform draw {k - 1} of 29 in [-1, 1] (seed 0)")
                )
                raise PolicyLoadError(
                    f"{path}: the action for the observation with {what} is not finite "
                    f"({action[0].tolist()}); refusing the model"
                )

    def _check_state_shapes(self, path: Path, batch: int) -> None:
        """Run the graph once on zeros: every state output must have its input's shape."""
        feeds = {self.input_name: np.zeros((batch, self.obs_dim), np.float32)}
        for name, (shape, dtype, value) in self._constant_specs.items():
            feeds[name] = np.full([batch if d is None else d for d in shape], value, dtype)
        for s in self.states:
            feeds[s.input] = np.zeros((s.layers, batch, s.hidden), np.float32)
        for b in self.spec.images:
            feeds[b.input] = np.zeros((batch, *b.input_shape), np.float32)
        try:
            outs = self.session.run([s.output for s in self.states], feeds)
        except Exception as exc:  # noqa: BLE001
            raise PolicyLoadError(
                f"{path}: running the model on a zero observation and zero state failed: {exc}"
            ) from None
        for s, value in zip(self.states, outs, strict=True):
            if value.shape != feeds[s.input].shape:
                raise PolicyLoadError(
                    f"{path}: recurrent state output '{s.output}' has shape {list(value.shape)}, "
                    f"its input '{s.input}' {list(feeds[s.input].shape)}; they must be equal"
                )

    # ------------------------------------------------------------------ inference
    def _bind(self, batch: int) -> None:
        if self._fixed_batch and batch != self._fixed_batch:
            raise ValueError(
                f"{self.path}: the graph has a fixed batch size {self._fixed_batch}, got {batch}"
            )
        self._obs = np.zeros((batch, self.obs_dim), np.float32)
        self._action = np.zeros((batch, self.act_dim), np.float32)
        # the graph's outputs in its own joint order when it differs (spec action.joints)
        self._graph_action = (
            self._action
            if self._joints is None
            else np.zeros((batch, self.spec.action.outputs), np.float32)
        )
        self._obs_value = ort.OrtValue.ortvalue_from_numpy(self._obs)
        self._action_value = ort.OrtValue.ortvalue_from_numpy(self._graph_action)
        self._binding.clear_binding_inputs()
        self._binding.clear_binding_outputs()
        self._binding.bind_ortvalue_input(self.input_name, self._obs_value)
        self._input, self._seen = self._obs, None
        self._binding.bind_ortvalue_output(self.output_name, self._action_value)
        self._constant_values = []  # keep the OrtValues alive with the binding
        #: the image inputs (spec ``images``), float32 (batch, *block.input_shape), bound:
        #: the runtime's camera stage writes each tick's image into them in place
        self.images = {
            b.input: np.zeros((batch, *b.input_shape), np.float32) for b in self.spec.images
        }
        for name, array in self.images.items():
            self._constant_values.append(ort.OrtValue.ortvalue_from_numpy(array))
            self._binding.bind_ortvalue_input(name, self._constant_values[-1])
        for name, (shape, dtype, value) in self._constant_specs.items():
            array = np.full([batch if d is None else d for d in shape], value, dtype)
            self._constant_values.append(ort.OrtValue.ortvalue_from_numpy(array))
            self._binding.bind_ortvalue_input(name, self._constant_values[-1])
        pairs, self._state_values = [], []
        for s in self.states:
            pair = (
                np.zeros((s.layers, batch, s.hidden), np.float32),
                np.zeros((s.layers, batch, s.hidden), np.float32),
            )
            values = [ort.OrtValue.ortvalue_from_numpy(a) for a in pair]
            self._binding.bind_ortvalue_input(s.input, values[0])
            self._binding.bind_ortvalue_output(s.output, values[1])
            pairs.append(pair)
            self._state_values.append(values)  # keep the OrtValues alive with the buffers
        self._state_pairs = tuple(pairs)
        self._batch = batch
        if self.states:
            self.reset()

    def bind_batch(self, batch: int) -> None:
        """Bind the graph's inputs for ``batch`` envs now (a call with another batch does it
        too): the image inputs (:attr:`images`) the runtime writes before its first call are
        then of its batch.

        Raises:
            ValueError: the graph has a fixed batch size and ``batch`` differs."""
        if batch != self._batch:
            self._bind(batch)

    def _runner(self):
        """The session's public ``run_with_iobinding`` of :attr:`_binding`, bound once (not its
        C++ method behind the wrapper, a private attribute of ONNX Runtime: docs/speed.md)."""
        return partial(self.session.run_with_iobinding, self._binding)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """The actions for a batch of observations.

        Args:
            obs: float32 (envs, obs_dim), the spec's normalized observation (other float dtypes
                are converted).

        Returns:
            float32 (envs, act_dim). The array is a preallocated buffer, overwritten by the next
            call: copy what you keep.

        A recurrent policy reads each env's state and keeps the new one for the next call; a
        change of ``envs`` starts every env from its initial state. A caller passing the same
        float32 C-contiguous array on two calls in a row (the runtime's observation buffer) has
        it bound as the graph's input from then on, read in place instead of copied: the call
        is then the session's run and nothing else.

        Raises:
            ValueError: ``obs`` is not shaped (envs, obs_dim), or the graph has a fixed batch size
                and ``envs`` differs.
        """
        if obs is self._input:  # the caller's array, bound (checked when it was bound)
            self._run()
            return self._action if self._finish is None else self._finish()
        if obs.ndim != 2 or obs.shape[1] != self.obs_dim:
            raise ValueError(
                f"obs: expected shape (envs, {self.obs_dim}), got {tuple(np.shape(obs))}"
            )
        if obs.shape[0] != self._batch:
            self._bind(obs.shape[0])
        if obs is self._seen and obs.dtype == np.float32 and obs.flags.c_contiguous:
            self._bind_input(obs)  # the second call in a row with this array: read in place
        else:
            self._seen = obs
            if self._input is not self._obs:
                self._bind_input(self._obs)
            np.copyto(self._obs, obs, casting="same_kind")
        self._run()
        return self._action if self._finish is None else self._finish()

    def _bind_input(self, array: np.ndarray) -> None:
        """Bind ``array`` (float32 (batch, obs_dim), C-contiguous) as the graph's input."""
        value = self._obs_value
        if array is not self._obs:
            value = ort.OrtValue.ortvalue_from_numpy(array)  # shares its memory, keeps it alive
        self._binding.bind_ortvalue_input(self.input_name, value)
        self._input, self._seen = array, None

    def _finish_call(self) -> np.ndarray:
        """After the graph ran: its outputs scattered into joint order, the recurrent states
        carried over; the action."""
        if self._joints is not None:  # joints no output drives keep action 0
            self._action[:, self._joints] = self._graph_action
        for state_in, state_out in self._state_pairs:
            np.copyto(state_in, state_out)
        return self._action

    @property
    def graph_action(self) -> np.ndarray:
        """float32 (envs, ``spec.action.outputs``): the last call's action as the graph gave it
        (its own output order, before the spec's ``action.joints`` scatter it into joint
        order); the buffer is overwritten by the next call."""
        return self._graph_action

    def reset(self, envs: np.ndarray | None = None) -> None:
        """Set the recurrent state of some envs to its initial value (zeros, or the file's
        declared initial state). No-op for a feed-forward policy.

        Args:
            envs: Boolean mask (envs,) of the envs to reset; default all. A mask of another
                length than the current batch sets the batch size to its length (every env then
                starts from its initial state).

        Raises:
            ValueError: the graph has a fixed batch size and the mask's length differs.
        """
        if not self.states:
            return
        if envs is not None:
            envs = np.asarray(envs, dtype=bool).reshape(-1)
            if envs.shape[0] != self._batch:
                self._bind(envs.shape[0])
                return
        index = slice(None) if envs is None else envs
        for s, (state_in, _) in zip(self.states, self._state_pairs, strict=True):
            state_in[:, index, :] = 0.0 if s.initial is None else s.initial

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The recurrent state (copies), keyed by state input name: ``(layers, hidden)`` float32
        for env ``env``, or ``(layers, envs, hidden)`` for all. Empty for a feed-forward policy."""
        index = slice(None) if env is None else env
        return {
            s.input: state_in[:, index, :].copy()
            for s, (state_in, _) in zip(self.states, self._state_pairs, strict=True)
        }

    def load_state_dict(self, state: Mapping[str, np.ndarray], env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (for the same ``env``, or all envs).

        Raises:
            ValueError: a missing or unexpected key, or a shape that does not fit (for all envs,
                the batch is set from the arrays' axis 1 first).
        """
        expected = {s.input for s in self.states}
        if set(state) != expected:
            raise ValueError(f"policy state: expected keys {sorted(expected)}, got {sorted(state)}")
        if not self.states:
            return
        if env is None:
            batch = np.shape(next(iter(state.values())))[1:2]
            if batch and batch[0] != self._batch:
                self._bind(batch[0])
        index = slice(None) if env is None else env
        for s, (state_in, _) in zip(self.states, self._state_pairs, strict=True):
            value = np.asarray(state[s.input], dtype=np.float32)
            if value.shape != state_in[:, index, :].shape:
                raise ValueError(
                    f"policy state '{s.input}': expected shape "
                    f"{state_in[:, index, :].shape}, got {value.shape}"
                )
            state_in[:, index, :] = value

    @property
    def parity(self) -> dict[str, Any]:
        """The export's parity figures (empty for a foreign model)."""
        return dict(self.spec.parity)

    def __repr__(self) -> str:
        kind = f", state={[s.input for s in self.states]}" if self.states else ""
        return (
            f"OnnxPolicy('{self.path}', robot='{self.spec.robot}', obs_dim={self.obs_dim}, "
            f"act_dim={self.act_dim}, mode='{self.spec.action.mode}'{kind})"
        )


def _checked_model(path: Path) -> onnx.ModelProto:
    """The ONNX file read, its external data inlined, passed by ONNX's checker, its weights
    finite (``PolicyLoadError`` naming the file where not)."""
    model = read_model(path)
    if check_external_data(model, path):
        try:
            onnx.load_external_data_for_model(model, str(path.parent))
        except Exception as exc:  # noqa: BLE001
            raise PolicyLoadError(f"{path}: cannot read external data: {exc}") from None
    try:
        onnx.checker.check_model(model)
    except Exception as exc:  # noqa: BLE001 - onnx.checker.ValidationError
        raise PolicyLoadError(f"{path}: the ONNX checker rejects the model: {exc}") from None
    check_finite_weights(model, path)
    return model


def _session(model: onnx.ModelProto, path: Path) -> ort.InferenceSession:
    """ONNX Runtime's session of the validated bytes (it never reads the path again): one
    thread, sequential, every graph optimization, no spinning thread beside the control loop."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    # No busy-waiting thread beside the control loop, should a thread pool ever be made
    # (holosoma and openpilot set it too); with one intra-op thread the call is unchanged.
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.add_session_config_entry("session.inter_op.allow_spinning", "0")
    try:
        return ort.InferenceSession(
            model.SerializeToString(), options, providers=["CPUExecutionProvider"]
        )
    except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own exception types
        raise PolicyLoadError(f"{path}: ONNX Runtime cannot load the model: {exc}") from None
