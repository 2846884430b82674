"""``robot-import``: import a robot from its published description (URDF, or MJCF) into a robot
folder (:func:`sim2real.robots.importer.pipeline.import_robot`).

::

    robot-import example-robot-data:so_arm_description/urdf/so101.urdf --out robots/my_so101 \\
        --motor '*=sts3215'
    robot-import panda.urdf --out robots/panda --srdf panda.srdf \\
        --motor 'panda_joint[1-4]=ec90flat_hd101' --motor 'panda_joint[5-7]=ec45flat_hd101'
    robot-import my_arm.xml --out robots/my_arm --motor '*=ec45flat70_gp42c' --velocity '*=3.14'

``--drive-from POLICY`` reads the PD gains, default pose and control rate a policy records
(:func:`sim2real.deploy.spec.foreign.drive.policy_drive`): the command line lives on the deploy floor so
that the importer below it reads no policy.
"""

from __future__ import annotations

import argparse
import functools
import sys

from sim2real.deploy.spec.foreign.drive import policy_drive
from sim2real.robots.errors import Sim2RealError
from sim2real.robots.importer.pipeline import (
    DEFAULT_CONTROL_RATE,
    DEFAULT_PHYSICS_TIMESTEP,
    EXIT_REFUSED,
    import_robot,
)
from sim2real.robots.importer.source import BuiltModelError
from sim2real.robots.loading import motor_catalog


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of ``robot-import``'s options."""
    p = argparse.ArgumentParser(
        prog="robot-import",
        description=__doc__.split("::")[0].strip(),
        epilog=f"Motor models in the catalog: {', '.join(sorted(motor_catalog()))}",
    )
    p.add_argument("source", help="URDF or MJCF file, or PACKAGE:path (example-robot-data:...)")
    p.add_argument("--out", required=True, help="robot folder to write (its name = robot name)")
    p.add_argument("--srdf", default=None, help="SRDF with disable_collisions pairs")
    _add_joint_options(p)
    p.add_argument(
        "--control-rate",
        type=float,
        default=None,
        help=f"Hz (default: the --drive-from policy's, else {DEFAULT_CONTROL_RATE:g})",
    )
    p.add_argument(
        "--physics-timestep",
        type=float,
        default=None,
        help=f"s (default: the MJCF's <option timestep>, else {DEFAULT_PHYSICS_TIMESTEP:g})",
    )
    _add_model_options(p)
    _add_legged_options(p)
    return p


def _add_joint_options(p: argparse.ArgumentParser) -> None:
    """Add the per-joint options: motors, end effector, position and velocity limits."""
    p.add_argument(
        "--motor",
        action="append",
        default=[],
        metavar="JOINT=MODEL",
        help="motor of a joint (shell pattern, '*' = every joint): a catalog model or the path "
        "of a motor TOML file (the catalog's schema); repeatable",
    )
    p.add_argument(
        "--ee-site",
        default=None,
        metavar="LINK",
        help="link (MJCF: body or site) of the end effector",
    )
    p.add_argument(
        "--limit",
        action="append",
        default=[],
        metavar="JOINT=LOWER:UPPER",
        help="position limits (rad) for joints the description leaves unlimited, or to replace "
        "them (shell pattern); repeatable",
    )
    p.add_argument(
        "--velocity",
        action="append",
        default=[],
        metavar="JOINT=RAD_S",
        help="velocity limit (rad/s) where the description has none (MJCF) or to replace it; "
        "shell pattern; the motor's no-load speed still caps it; repeatable",
    )


def _add_model_options(p: argparse.ArgumentParser) -> None:
    """Add the options of the model written: replace, meshes, collision boxes, MuJoCo options."""
    p.add_argument("--force", action="store_true", help="replace an existing --out folder")
    p.add_argument(
        "--drop-missing-meshes",
        action="store_true",
        help="drop the geoms whose mesh file is missing (each printed) instead of refusing",
    )
    p.add_argument(
        "--link-boxes",
        action="store_true",
        help="one collision box per link around all its meshes (coarser, fewer pairs; what "
        "robot-import wrote before one box per mesh) instead of one box per mesh",
    )
    p.add_argument(
        "--mesh-boxes",
        action="store_true",
        help="an MJCF's collision meshes become their bounding boxes (what robot-import wrote "
        "before) instead of their convex hulls",
    )
    p.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a MuJoCo <option> setting of the robot's MJCF (integrator, iterations, "
        "ls_iterations, cone, solver, impratio, ...) over the description's own, e.g. a training "
        "stack's iterations=10; repeatable",
    )


def _add_legged_options(p: argparse.ArgumentParser) -> None:
    """Add the floating-base (legged) robot options: feet, IMU, drive, Unitree table."""
    legged = p.add_argument_group("floating-base (legged) robots")
    legged.add_argument(
        "--floating-base",
        action="store_true",
        help="a legged robot: free joint, floor, IMU and foot contact sensors",
    )
    legged.add_argument("--foot", action="append", default=[], metavar="LINK", help="a foot link")
    legged.add_argument(
        "--imu", default=None, metavar="LINK", help="the IMU link (MJCF: or a site)"
    )
    for flag, unit in (("--kp", "N m/rad"), ("--kd", "N m s/rad"), ("--home", "rad")):
        legged.add_argument(
            flag,
            action="append",
            default=[],
            metavar="JOINT=VALUE",
            help=f"{flag[2:]} ({unit}) of joints (shell pattern); repeatable",
        )
    legged.add_argument(
        "--drive-from",
        default=None,
        metavar="POLICY",
        help="kp, kd, home and control rate from a policy's own contract (an ONNX file with "
        "mjlab or holosoma metadata, Unitree's params/deploy.yaml or Isaac Lab's params/env.yaml "
        "beside it; rl_sar's config.yaml beside its policy.onnx or TorchScript policy.pt); --kp, "
        "--kd, --home after it win",
    )
    legged.add_argument(
        "--keyframe",
        default=None,
        metavar="NAME",
        help="the MJCF <key> whose pose is home where no --home or policy gives it (default: the "
        "key named 'home', else the first); an MJCF's <position> kp and kv likewise come before "
        "the importer's rule",
    )
    legged.add_argument(
        "--note", action="append", default=[], help="a comment line for robot.toml's header"
    )
    legged.add_argument(
        "--target-limits",
        choices=("pd", "motion"),
        default="pd",
        help="smoother and guard acceleration and jerk limits: 'pd' (default) lets a PD target "
        "move, rest to rest within one control period, as far as the drive's full torque reaches "
        "(effort / kp); 'motion' only what the joint itself can accelerate (the arms' rule)",
    )
    legged.add_argument(
        "--unitree",
        default=None,
        metavar="FAMILY",
        help="a Unitree quadruped: write its [unitree] table (motor slots from the joint names; "
        "unitree_go or unitree_hg) for deploy-run --backend unitree",
    )
    legged.add_argument(
        "--unitree-damping-kd", type=float, default=None, help="N m s/rad of the damping command"
    )
    legged.add_argument("--unitree-ramp-kp", type=float, default=None, help="bring-up N m/rad")
    legged.add_argument("--unitree-ramp-kd", type=float, default=None, help="bring-up N m s/rad")


def main(argv: list[str] | None = None) -> int:
    """The ``robot-import`` command: parse ``argv``, import the robot; return the exit status."""
    args = build_parser().parse_args(argv)
    if args.unitree is not None and args.unitree_damping_kd is None:
        print("robot-import: error: --unitree needs --unitree-damping-kd", file=sys.stderr)
        return EXIT_REFUSED
    try:
        import_robot(
            args.source,
            args.out,
            srdf=args.srdf,
            motors=args.motor,
            ee_site=args.ee_site,
            limits=args.limit,
            velocities=args.velocity,
            control_rate=args.control_rate,
            physics_timestep=args.physics_timestep,
            force=args.force,
            drop_missing_meshes=args.drop_missing_meshes,
            link_boxes=args.link_boxes,
            mesh_boxes=args.mesh_boxes,
            floating_base=args.floating_base,
            feet=args.foot,
            imu=args.imu,
            kp=args.kp,
            kd=args.kd,
            home=args.home,
            target_limits=args.target_limits,
            notes=args.note,
            command=["robot-import", *(sys.argv[1:] if argv is None else argv)],
            unitree=_unitree_table(args),
            drive=_drive(args),
            options=args.option,
            keyframe=args.keyframe,
        )
    except BuiltModelError as exc:  # MuJoCo's compiler on the model the import built
        print(f"robot-import: error: {args.source}: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except Sim2RealError as exc:  # a refusal: the import's, the contract's, a motor file's
        print(f"robot-import: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    return 0


def _unitree_table(args) -> dict | None:
    """Return the ``[unitree]`` table of ``--unitree`` and its gains (None without it)."""
    if args.unitree is None:
        return None
    return {
        "family": args.unitree,
        "damping_kd": args.unitree_damping_kd,
        "ramp_kp": args.unitree_ramp_kp,
        "ramp_kd": args.unitree_ramp_kd,
    }


def _drive(args):
    """Return the ``--drive-from`` policy's drive reader (None without it)."""
    if args.drive_from is None:
        return None
    return functools.partial(policy_drive, args.drive_from)


if __name__ == "__main__":
    raise SystemExit(main())
