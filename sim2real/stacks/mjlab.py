"""mjlab (mujocolab/mjlab): its ONNX exports (the metadata of its exporter) and the training
domain of its run folder's ``params/env.yaml``."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="mjlab",
        about="mjlab, a training stack on MuJoCo Warp (mujocolab/mjlab)",
        rank=10,
        detect="sim2real.deploy.spec.foreign.mjlab:detect",
        contract="sim2real.deploy.spec.foreign.mjlab:read",
        domain="sim2real.eval.world.env_yaml_domain:DOMAIN",
        clips=Absent("mjlab's tracking task reads BeyondMimic's NPZ (the beyondmimic stack's)"),
        terrain=Absent("the soak does not read env.yaml's terrain generator"),
        own_loop=Absent("no replica of mjlab's play loop is written yet"),
        tracking_loop=Absent("no replica of mjlab's play loop is written yet"),
    )
)
