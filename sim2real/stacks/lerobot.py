"""LeRobot (huggingface/lerobot 0.4): the folder ``lerobot-train`` writes for an ACT policy
(``config.json``, ``model.safetensors``, the processors' normalisation statistics), read by
:mod:`sim2real.deploy.spec.foreign.lerobot` and exported by ``policy-export FOLDER --robot R``
(:mod:`sim2real.deploy.export.lerobot_act`) into an ONNX file of action chunks that
:class:`~sim2real.deploy.policy.lerobot_policy.LeRobotChunkPolicy` runs in the runtime beside
the servo loop."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="lerobot",
        about="LeRobot's ACT policies (huggingface/lerobot 0.4.4, policies/act)",
        rank=80,
        detect=Absent(
            "its files are a training folder, not an ONNX graph: policy-export recognises the "
            "folder (sim2real.deploy.spec.foreign.lerobot.detect) before any export"
        ),
        contract=Absent(
            "a chunked policy (an action chunk per call) is no PolicySpec: its contract is the "
            "ONNX metadata lerobot_contract (sim2real.deploy.spec.foreign.lerobot.read_onnx)"
        ),
        domain=Absent("LeRobot trains from recorded demonstrations: no randomised domain"),
        clips=Absent("LeRobot's datasets are demonstrations, not reference motions"),
        terrain=Absent("its robots are fixed-base arms"),
        own_loop=Absent(
            "its own loop is lerobot's select_action, which the export's parity check runs "
            "(sim2real.deploy.export.lerobot_act) where the extra 'lerobot' is installed"
        ),
        tracking_loop=Absent("its policies are arm demonstrations, not motion tracking"),
    )
)
