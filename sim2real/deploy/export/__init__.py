"""policy-export: a trained policy -> ONNX with its contract, accepted only after a parity gate.

Usage::

    policy-export SOURCE [--spec SPEC.json] [--out FILE.onnx] [--trust-pickle]
                  [--vecnormalize FILE(.npz|.json|.pkl)] [--activation elu|tanh|relu]
                  [--robot NAME|PATH] [--exporter torchscript|dynamo] [--parity-tolerance X]
    policy-export SOURCE --from-config DEPLOY.yaml --robot DIR [--write-robot]
    policy-export --inspect FILE     # what FILE is (sim2real.deploy.export.inspect_policy); nothing exported

Exit status (:mod:`~.cli`): 0 exported, 1 parity failure (:class:`ParityError`), 2 bad input
(:class:`ExportError`), 3 internal error (a bug). The format is detected from the content
(:mod:`~.load`), one module each: our checkpoint (:mod:`~.checkpoint`), TorchScript
(:mod:`~.torchscript`; legged_gym's stateful LSTM: :mod:`~.torchscript_lstm`), SB3 PPO / SAC and
RecurrentPPO zips (:mod:`~.sb3`, :mod:`~.sb3_recurrent`), rsl_rl checkpoints (:mod:`~.rsl_rl`,
:mod:`~.rsl_rl_recurrent`), a pickled ``nn.Module`` only with ``--trust-pickle``. Every source but
our checkpoint needs ``--spec``, or ``--from-config`` (:mod:`~.deploy_config`), except TorchScript
beside a contract the toolkit reads (rl_sar's ``config.yaml``): that one is written as the bare
``obs`` -> ``actions`` graph the contract is read beside (:mod:`~.folder_torchscript`).

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

from sim2real.deploy.export.errors import ExportError, ParityError
from sim2real.deploy.export.graph import (
    EXPORTERS,
    OPSET,
    package_version,
    set_metadata,
    to_onnx,
    tool_versions,
)
from sim2real.deploy.export.load import load_source
from sim2real.deploy.export.network import check_finite_tensors
from sim2real.deploy.export.noise_floor import NOISE_MULTIPLIER, NoiseFloor
from sim2real.deploy.export.parity import (
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
from sim2real.deploy.export.pipeline import ExportResult, export_policy, failed_path, run_export
from sim2real.deploy.export.rsl_rl_normalizer import RSL_RL_EPS, rsl_rl_normalizer
from sim2real.deploy.export.sb3 import sb3_actor
from sim2real.deploy.export.source import (
    ActionClip,
    Normalize,
    NormalizeNoClip,
    SourcePolicy,
    normalizer_module,
)
from sim2real.deploy.export.torchscript import load_torchscript
from sim2real.deploy.export.vecnormalize import load_vecnormalize

__all__ = [
    "EXPORTERS",
    "GOAL_PERIOD",
    "NOISE_MULTIPLIER",
    "OPSET",
    "PARITY_BATCH1",
    "PARITY_SAMPLES",
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
    "normalizer_module",
    "package_version",
    "parity_observations",
    "rsl_rl_normalizer",
    "run_export",
    "sample_goals",
    "sb3_actor",
    "set_metadata",
    "static_parity",
    "to_onnx",
    "tool_versions",
]
