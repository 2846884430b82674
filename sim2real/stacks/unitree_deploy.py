"""Unitree's C++ deployment of unitree_rl_lab and unitree_rl_mjlab policies: ``params/deploy.yaml``
beside ``exported/policy.onnx``, the run folder's ``env.yaml`` (the training domain), and the
deployment's own loop."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="unitree_deploy",
        about="Unitree's deploy.yaml runtime (unitree_rl_lab's and unitree_rl_mjlab's deploy/)",
        rank=30,
        detect="sim2real.deploy.spec.foreign.unitree_deploy:detect",
        contract="sim2real.deploy.spec.foreign.unitree_deploy:read",
        domain="sim2real.eval.world.env_yaml_domain:DOMAIN",
        clips=Absent("Unitree's deploy.yaml policies play no clip"),
        terrain=Absent("the deployment runs on the robot's ground: no terrain of its own"),
        own_loop="sim2real.stacks.loops.deploy_yaml_loop:run",
        tracking_loop=Absent(
            "Unitree's deploy.yaml policies are velocity-commanded: no motion to track"
        ),
    )
)
