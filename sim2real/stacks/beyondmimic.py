"""BeyondMimic (HybridRobotics/whole_body_tracking): its motion clips (``csv_to_npz.py``'s NPZ,
the motion its exporter bakes into the ONNX file). Its policies are Isaac Lab exports (the
isaaclab stack reads their contract)."""

from sim2real.deploy.core.stacks import Absent, Stack, register_stack

STACK = register_stack(
    Stack(
        name="beyondmimic",
        about="BeyondMimic's whole-body tracking (HybridRobotics/whole_body_tracking)",
        rank=70,
        detect=Absent("its policies are Isaac Lab exports: the isaaclab stack recognises them"),
        contract=Absent("its policies' contract is Isaac Lab's (the isaaclab stack's reader)"),
        domain=Absent("its training domain is its run folder's env.yaml (the isaaclab stack's)"),
        clips="sim2real.deploy.tasks.motion.formats:BEYONDMIMIC_CLIPS",
        terrain=Absent("its tracking tasks run on a plane"),
        own_loop=Absent("no replica of its play loop is written yet"),
        tracking_loop=Absent("no replica of its play loop is written yet"),
    )
)
