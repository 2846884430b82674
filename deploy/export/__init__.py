"""policy-export: a trained policy -> ONNX with its contract, accepted only after a parity gate.

Usage::

    policy-export SOURCE [--spec SPEC.json] [--out FILE.onnx] [--trust-pickle]
                  [--vecnormalize FILE(.npz|.json|.pkl)] [--activation elu|tanh|relu]
                  [--robot NAME|PATH] [--exporter torchscript|dynamo] [--parity-tolerance X]
    policy-export SOURCE --from-config DEPLOY.yaml --robot DIR [--write-robot]
    policy-export --inspect FILE     # what FILE is (deploy.export.inspect_policy); nothing exported

Exit status (:mod:`~.cli`): 0 exported, 1 parity failure (:class:`ParityError`), 2 bad input
(:class:`ExportError`), 3 internal error (a bug). The format is detected from the content
(:mod:`~.load`), one module each: our checkpoint (:mod:`~.checkpoint`), TorchScript
(:mod:`~.torchscript`; legged_gym's stateful LSTM: :mod:`~.torchscript_lstm`), SB3 PPO / SAC and
RecurrentPPO zips (:mod:`~.sb3`, :mod:`~.sb3_recurrent`), rsl_rl checkpoints (:mod:`~.rsl_rl`,
:mod:`~.rsl_rl_recurrent`), a pickled ``nn.Module`` only with ``--trust-pickle``. Every source but
our checkpoint needs ``--spec``, or ``--from-config`` (:mod:`~.deploy_config`).

format              what is read
==================  ==========================================================================
our checkpoint      ``deploy.policy.mlp_checkpoint`` format (MLP, spec and normalizer inside;
``--spec``
                    optional and then must agree)
TorchScript         ``torch.jit.save`` archive; needs ``--spec``. Stateful TorchScript is refused
                    (:func:`deploy.export.torchscript_lstm.check_stateless`), except
legged_gym LSTM     legged_gym's ``PolicyExporterLSTM`` (buffers ``hidden_state``/``cell_state``
                    updated in place): the buffers become explicit state I/O and the file itself
                    is a parity reference (:mod:`deploy.export.torchscript_lstm`). Needs ``--spec``.
SB3 PPO / SAC       Stable-Baselines3 ``.zip``, read without unpickling: ``policy.pth`` (state
                    dict, ``weights_only``) and the ``data`` JSON. The deterministic actor is
                    rebuilt from the state-dict shapes: PPO ``mlp_extractor.policy_net`` +
                    ``action_net`` (Tanh by default, ``tanh`` output if ``squash_output``); SAC
                    ``actor.latent_pi`` + ``actor.mu`` then ``tanh`` (ReLU by default). The
                    activation comes from ``policy_kwargs.activation_fn`` when recorded;
                    ``--activation`` overrides. The action space must be the Box [-1, 1]
                    (the spec scales actions). Needs ``--spec``.
RecurrentPPO        SB3-contrib ``MlpLstmPolicy`` zip, read the same way: ``lstm_actor`` +
                    policy net + ``action_net`` (:mod:`deploy.export.sb3_recurrent`). ``--spec``.
rsl_rl              ``{"model_state_dict": {"actor.0.weight", ...}, ...}``: the ``actor.*`` MLP
                    (ELU by default) and rsl_rl's ``EmpiricalNormalization``, either
                    ``obs_norm_state_dict`` (rsl_rl 1.x/2.x) or ``actor_obs_normalizer.*`` in the
                    model state dict (3.x): ``(obs - _mean) / (_std + 0.01)`` (rsl_rl's default
                    eps, not stored in the file), no clip. Needs ``--spec``.
rsl_rl recurrent    ``ActorCriticRecurrent``: ``memory_a.rnn`` (LSTM or GRU) + the ``actor.*`` MLP
                    (+ normalizer as above), :mod:`deploy.export.rsl_rl_recurrent`; the graph has
                    explicit state I/O (:mod:`deploy.export.recurrent`). Needs ``--spec``.
pickled nn.Module   ``torch.save(module)``: only with ``--trust-pickle`` (unpickling runs code);
                    needs ``--spec``
==================  ==========================================================================

``--vecnormalize`` adds SB3 ``VecNormalize`` statistics, ``clip((obs - mean) / sqrt(var + epsilon),
-clip_obs, clip_obs)``, to a source without a normalizer: an ``.npz`` with arrays ``mean``,
``var``, ``clip_obs``, ``epsilon``, a ``.json`` with the same keys (lists and numbers), or SB3's own
pickle (``VecNormalize.save``; needs ``--trust-pickle``). To write the safe form::

    np.savez("vecnormalize.npz", mean=vn.obs_rms.mean, var=vn.obs_rms.var,
             clip_obs=vn.clip_obs, epsilon=vn.epsilon)

The graph: input ``obs`` float32 [batch, obs_dim] (the spec's normalized observation), output
``action`` float32 [batch, act_dim], dynamic batch axis, opset 18 (``OPSET``); it bakes in the
empirical observation normalizer (if any) and the action clip ``[-clip, clip]`` of the spec.
Exporter: torch's TorchScript-based exporter (``torch.onnx.export(dynamo=False)``) by default: it
takes TorchScript sources and needs no onnxscript; ``--exporter dynamo`` uses the
``torch.export`` exporter instead (not for TorchScript sources). ``onnx.checker.check_model``
(full check) must pass.

Metadata (``model.metadata_props``): ``policy_spec`` (the PolicySpec JSON with ``baked`` and
``parity`` filled), ``source_sha256``, ``tool_versions`` (JSON: torch, onnx, onnxruntime, this
package, python), ``parity`` (JSON), ``source_format``, ``exporter``.

Recurrent sources get the graph ``obs``, ``h_in`` (, ``c_in``) -> ``action``, ``h_out``
(, ``c_out``), state ``[layers, batch, hidden]`` (TorchScript-based exporter only), and a parity
gate over sequences: step 1 is replaced by :func:`deploy.export.parity.sequence_parity` (500
sequential steps, state carried, resets half way), and the replay of step 2 carries the state on
both sides. A source that runs as it is (legged_gym's stateful TorchScript) is also stepped
against the ONNX for 500 steps at batch 1 (figures ``source_max_abs_error``, ``source_steps``).

Parity gate (max abs error over all action entries), both run through
:class:`deploy.policy.onnx_policy.OnnxPolicy` exactly as the runtime runs it. The tolerance is
judged against what float32 can reach (:mod:`deploy.export.noise_floor`): a float64 copy of the
source runs on the same observations, the largest ``|float32 - float64|`` is the network's float32
noise floor, and the tolerance is ``max(TOLERANCE, NOISE_MULTIPLIER x floor)`` (1e-5, 4); a
recurrent state is judged the same way against its own floor. A source that cannot run in float64
keeps the absolute ``TOLERANCE`` (the figures and messages say why); ``--parity-tolerance X`` sets
the tolerance. The runs:
    1. 1,000 observations uniform in [-1.2, 1.2] per normalized entry, plus edge cases (zeros,
       +-1, +-1.2, +- each block's clip, each entry alone at +-1), in one batch and the first 32
       again one by one (batch 1), ONNX Runtime vs the torch module (normalizer and clip included);
    2. a closed-loop replay of 1,000 control ticks on the MuJoCo plant (``SimBackend``, 2 envs, the
       spec's control mode): observations from the plant's true state (``RobotState`` +
       ``Kinematics`` + ``spec.observation``), goals drawn from the robot's task region every 2 s,
       the ONNX action through ``spec.action_to_target`` to ``plant.write``; torch and ONNX compared
       at every tick.

The package, one module per concept (each module's docstring says what it holds):

==========================  ==================================================================
module                      what it holds
==========================  ==================================================================
:mod:`~.pipeline`           :func:`export_policy`, :func:`run_export`: load, build, gate, write
:mod:`~.cli`                the ``policy-export`` command (:func:`main`), exit statuses
:mod:`~.load`               :func:`load_source`: format detection and dispatch, pickled modules
:mod:`~.checkpoint`         our checkpoints
:mod:`~.torchscript`        TorchScript (stateless)
:mod:`~.torchscript_lstm`   legged_gym's stateful LSTM TorchScript
:mod:`~.sb3`                SB3 PPO / SAC zips (:func:`sb3_actor`)
:mod:`~.sb3_recurrent`      SB3-contrib RecurrentPPO zips
:mod:`~.rsl_rl`             rsl_rl checkpoints and their normalizer
:mod:`~.rsl_rl_recurrent`   rsl_rl ``ActorCriticRecurrent`` checkpoints
:mod:`~.vecnormalize`       ``--vecnormalize`` statistics
:mod:`~.source`             :class:`SourcePolicy` and the modules wrapped around its net
:mod:`~.network`            checks every loader runs; MLPs rebuilt from state dicts
:mod:`~.recurrent`          the recurrent module with explicit state I/O
:mod:`~.graph`              the ONNX graph (exporters, checker, metadata)
:mod:`~.parity`             the parity gate
:mod:`~.noise_floor`        the gate's tolerance: the float32 noise floor of the source
:mod:`~.deploy_config`      ``--from-config``: a legged_gym deploy config as the spec
:mod:`~.inspect_policy`     ``policy-export --inspect`` (ONNX; torch files: :mod:`~.inspect_torch`;
                            the report's entries and text: :mod:`~.inspect_report`)
:mod:`~.errors`             :class:`ExportError`, :class:`ParityError`, :class:`InspectError`
==========================  ==================================================================
=======
The graph (:mod:`~.graph`): ``obs`` float32 [batch, obs_dim] -> ``action`` float32 [batch,
act_dim], dynamic batch axis, opset ``OPSET``, the observation normalizer (:mod:`~.source`,
:mod:`~.vecnormalize`) and the spec's action clip baked in, the PolicySpec, source hash, tool
versions and parity figures in its metadata; a recurrent source adds its state, ``h_in`` (,
``c_in``) -> ``h_out`` (, ``c_out``), shaped [layers, batch, hidden] (:mod:`~.recurrent`). It is
written under a temporary name and moved into place (:mod:`~.pipeline`) only after the parity gate
(:mod:`~.parity`) passes within its tolerance (:mod:`~.noise_floor`); a candidate that fails is
kept as ``<stem>.parity-failed.onnx``. :mod:`~.network` holds the checks every loader runs and the
MLPs rebuilt from state dicts. Formats and options in use: README.md, "Export a policy".
"""

from deploy.export.cli import (
    EXIT_BAD_INPUT,
    EXIT_INTERNAL,
    EXIT_OK,
    EXIT_PARITY,
    POLICIES_DIR,
    main,
    resolve_policy_path,
)
from deploy.export.errors import ExportError, ParityError
from deploy.export.graph import (
    EXPORTERS,
    OPSET,
    package_version,
    set_metadata,
    to_onnx,
    tool_versions,
)
from deploy.export.load import load_source
from deploy.export.network import check_finite_tensors
from deploy.export.noise_floor import NOISE_MULTIPLIER, NoiseFloor
from deploy.export.parity import (
    GOAL_PERIOD,
    PARITY_BATCH1,
    PARITY_SAMPLES,
    REPLAY_ENVS,
    REPLAY_TICKS,
    TOLERANCE,
    closed_loop_parity,
    parity_observations,
    sample_goals,
    static_parity,
)
from deploy.export.pipeline import ExportResult, export_policy, failed_path, run_export
from deploy.export.rsl_rl import RSL_RL_EPS, rsl_rl_normalizer
from deploy.export.sb3 import sb3_actor
from deploy.export.source import (
    ActionClip,
    Normalize,
    NormalizeNoClip,
    SourcePolicy,
    normalizer_module,
)
from deploy.export.torchscript import load_torchscript
from deploy.export.vecnormalize import load_vecnormalize

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_INTERNAL",
    "EXIT_OK",
    "EXIT_PARITY",
    "EXPORTERS",
    "GOAL_PERIOD",
    "NOISE_MULTIPLIER",
    "OPSET",
    "PARITY_BATCH1",
    "PARITY_SAMPLES",
    "POLICIES_DIR",
    "REPLAY_ENVS",
    "REPLAY_TICKS",
    "RSL_RL_EPS",
    "TOLERANCE",
    "ActionClip",
    "ExportError",
    "ExportResult",
    "NoiseFloor",
    "Normalize",
    "NormalizeNoClip",
    "ParityError",
    "SourcePolicy",
    "check_finite_tensors",
    "closed_loop_parity",
    "export_policy",
    "failed_path",
    "load_source",
    "load_torchscript",
    "load_vecnormalize",
    "main",
    "normalizer_module",
    "package_version",
    "parity_observations",
    "resolve_policy_path",
    "rsl_rl_normalizer",
    "run_export",
    "sample_goals",
    "sb3_actor",
    "set_metadata",
    "static_parity",
    "to_onnx",
    "tool_versions",
]
