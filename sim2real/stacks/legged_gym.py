"""legged_gym and its forks (unitree_rl_gym, HIMLoco, humanoid-gym): the task's config class read
as text (its training domain and terrain). Its exports carry no contract: ``policy-export
--deploy-config`` reads unitree_rl_gym's deploy yaml into our spec."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="legged_gym",
        about="legged_gym and its forks (leggedrobotics/legged_gym; unitree_rl_gym, HIMLoco, humanoid-gym)",
        rank=60,
        detect=Absent("its TorchScript and ONNX exports record no contract to recognise them by"),
        contract=Absent(
            "no contract in its files: policy-export --deploy-config reads its deploy yaml"
        ),
        domain="sim2real.eval.world.legged_gym_domain:DOMAIN",
        clips=Absent("legged_gym's tasks play no clip"),
        terrain="sim2real.eval.world.terrain_ranges:TerrainRanges",
        own_loop="sim2real.stacks.loops.unitree_rl_gym:controller",
        tracking_loop=Absent("its policies are velocity-commanded: no motion to track"),
    )
)
