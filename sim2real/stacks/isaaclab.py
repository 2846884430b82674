"""Isaac Lab and rsl_rl (isaac-sim/IsaacLab, unitreerobotics/unitree_rl_lab): a bare graph
``obs`` -> ``actions`` read with its run folder's ``params/env.yaml``, which also holds its
training domain."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="isaaclab",
        about="Isaac Lab and rsl_rl exports (isaac-sim/IsaacLab; unitree_rl_lab's tasks)",
        rank=50,
        detect="sim2real.deploy.spec.foreign.isaaclab:detect",
        contract="sim2real.deploy.spec.foreign.isaaclab:read",
        domain="sim2real.eval.world.env_yaml_domain:DOMAIN",
        clips=Absent(
            "Isaac Lab writes no clip format of its own (BeyondMimic's is the beyondmimic stack's)"
        ),
        terrain=Absent("the soak does not read env.yaml's terrain generator"),
        own_loop=Absent(
            "Isaac Lab's own loop is Isaac Sim's; unitree_rl_lab's deployment is unitree_deploy's"
        ),
        tracking_loop=Absent(
            "its tracking policies' own loop is BeyondMimic's or holosoma's: no replica"
        ),
    )
)
