"""holosoma (amazon-far/holosoma): its ONNX exports (metadata ``dof_names``, ``kp``,
``experiment_config``; locomotion and whole-body tracking), the training domain their
``experiment_config`` records, and its motion clips (NPZ, the motion baked in a WBT export)."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="holosoma",
        about="holosoma, a training stack (amazon-far/holosoma)",
        rank=20,
        detect="sim2real.deploy.spec.foreign.holosoma:detect",
        contract="sim2real.deploy.spec.foreign.holosoma:read",
        domain="sim2real.eval.world.holosoma_domain:DOMAIN",
        clips="sim2real.deploy.tasks.motion.formats:HOLOSOMA_CLIPS",
        terrain=Absent("the soak does not read holosoma's terrain config (its plane is run)"),
        own_loop=Absent("no replica of holosoma's own sim2sim loop is written yet"),
        tracking_loop=Absent("no replica of holosoma's own sim2sim loop is written yet"),
    )
)
