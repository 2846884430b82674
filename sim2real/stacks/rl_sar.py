"""rl_sar (fan-ziqi/rl_sar e384912): its policy folders (``config.yaml`` beside the policy,
``base.yaml`` above it), their clips (CSV), and its own MuJoCo loops (legged and tracking)."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="rl_sar",
        about="rl_sar, a deployment stack (fan-ziqi/rl_sar e384912)",
        rank=40,
        detect="sim2real.deploy.spec.foreign.rl_sar:detect",
        contract="sim2real.deploy.spec.foreign.rl_sar:read",
        domain=Absent(
            "rl_sar deploys policies trained elsewhere: its config.yaml records no randomization "
            "(the training stack's config is read instead: legged_gym's, Isaac Lab's env.yaml)"
        ),
        clips="sim2real.deploy.tasks.motion.formats:RL_SAR_CLIPS",
        terrain=Absent("rl_sar runs on its simulator's scene: it describes no terrain of its own"),
        own_loop="sim2real.stacks.loops.himloco_terrain_loop:run",
        tracking_loop="sim2real.stacks.loops.rl_sar_pushed:TRACKING_LOOP",
    )
)
