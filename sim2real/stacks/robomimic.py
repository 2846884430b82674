"""RoboMimic_Deploy (ccrpRepo/RoboMimic_Deploy ffe3d40): its phase-clocked dance's own loop. rl_sar's
``robomimic`` folders wrap the same networks (the rl_sar stack reads their contract)."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="robomimic",
        about="RoboMimic_Deploy, a deployment stack (ccrpRepo/RoboMimic_Deploy ffe3d40)",
        rank=80,
        detect=Absent("its ONNX files record nothing to recognise them by; rl_sar's folders do"),
        contract=Absent(
            "its Dance.yaml is read through rl_sar's robomimic folders (the rl_sar stack's)"
        ),
        domain=Absent("a deployment stack: it records no training domain"),
        clips=Absent("its dances are phase-clocked: no clip file"),
        terrain=Absent("it runs on a plane"),
        own_loop="sim2real.stacks.loops.robomimic_dance:run",
        tracking_loop="sim2real.stacks.loops.robomimic_dance:TRACKING_LOOP",
    )
)
