"""Import a robot from its published description (URDF, or MJCF) into a robot folder.

::

    robot-import example-robot-data:so_arm_description/urdf/so101.urdf --out robots/my_so101 \\
        --motor '*=sts3215'
    python -m robots.importer.cli panda.urdf --out robots/panda --srdf panda.srdf \\
        --motor 'panda_joint[1-4]=ec90flat_hd101' --motor 'panda_joint[5-7]=ec45flat_hd101'
    robot-import my_arm.xml --out robots/my_arm --motor '*=ec45flat70_gp42c' --velocity '*=3.14'

It writes ``<out>/<name>.xml`` (MJCF made by MuJoCo's own URDF or MJCF compiler through
``mujoco.MjSpec``: radians, explicit inertials, no actuators, one ``ee`` site) and
``<out>/robot.toml`` (joint order and limits from the description, capped by the motors'
capabilities; motors from the catalog ``robots/motors/``; sensors from the motors; collision
pairs; home pose; task region). Meshes are never copied: the MJCF's ``meshdir`` names the
installed package (``package://...``) and :func:`robots.load_robot` resolves it. Every output is
checked with :func:`robots.load_robot` (MuJoCo/Pinocchio agreement) before it is moved into
place: a failed import leaves nothing.

The source is a URDF (root ``<robot>``, :mod:`robots.importer.urdf`) or an MJCF (root
``<mujoco>``, :mod:`robots.importer.mjcf`); both become a
:class:`robots.importer.urdf.PreparedSource`, and everything after that is the same code.
Errors (:class:`RobotImportError`, exit code 3) are one line naming the file, the element and
what was expected. The geometry and model helpers are in :mod:`robots.importer.model`.
"""

from __future__ import annotations

import argparse
import fnmatch
import shutil
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from robots.importer.mjcf import prepare_mjcf
from robots.importer.model import (
    build_spec,
    cap_limits,
    choose_collision_pairs,
    choose_ee_body,
    derive_motion_limits,
    sample_workspace,
    write_robot_toml,
)
from robots.importer.urdf import PreparedSource, RobotImportError, SrdfInfo, prepare_urdf, read_srdf
from robots.loading import (
    PACKAGE_SCHEME,
    _resolved_mjcf,
    load_motor,
    load_robot,
    motor_catalog,
    package_root,
)
from robots.robot import RobotSpecError
from robots.schema import MotorConfig

__all__ = ["ImportReport", "RobotImportError", "import_robot", "main", "resolve_source"]

#: Exit code of a refused import.
EXIT_REFUSED = 3
#: Default control rate (Hz) and physics timestep (s) of an imported robot: a serial-bus servo
#: arm is read and written at about 100 Hz (six STS3215 at 1 Mbps: ~1 ms per sync read/write).
DEFAULT_CONTROL_RATE = 100.0
DEFAULT_PHYSICS_TIMESTEP = 0.002


@dataclass
class ImportReport:
    """What an import did: output folder, joints, the limits it lowered and how long it took (s).

    ``lowered``: one ``(joint, quantity, description value, motor value, unit)`` per limit the
    motor capped. ``notes``: every other decision printed (frozen joints, fitted boxes, ...).
    """

    out: Path
    joints: list[str]
    lowered: list[tuple[str, str, float, float, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0


def resolve_source(source: str) -> Path:
    """Path of a description named ``PACKAGE:relative/path`` (e.g.
    ``example-robot-data:so_arm_description/urdf/so101.urdf``, looked up under the installed
    package's folder and its ``robots/`` folder) or a plain path.

    Raises:
        RobotImportError: no such file.
    """
    plain = Path(source)
    if plain.is_file():
        return plain.resolve()
    if ":" in source and not plain.exists():
        package, _, rel = source.partition(":")
        try:
            root = package_root(package)
        except RobotSpecError as exc:
            raise RobotImportError(f"{source}: {exc}") from None
        for candidate in (root / rel, root / "robots" / rel):
            if candidate.is_file():
                return candidate.resolve()
        raise RobotImportError(
            f"{source}: no file '{rel}' in package '{package}' ({root}, {root / 'robots'})"
        )
    raise RobotImportError(f"{source}: no such file (expected a URDF or MJCF file, or PKG:path)")


def _assign_motors(urdf: Path, joints: list[str], flags: list[str]) -> dict[str, str]:
    """Joint -> motor model from ``--motor JOINT=MODEL`` flags (shell patterns; later flags win)."""
    chosen: dict[str, str] = {}
    catalog = motor_catalog()
    for flag in flags:
        pattern, sep, model = flag.partition("=")
        if not sep or not pattern or not model:
            raise RobotImportError(f"--motor '{flag}': expected JOINT=MODEL (JOINT may be '*')")
        if model not in catalog:
            raise RobotImportError(
                f"--motor '{flag}': motor model '{model}' is not in the catalog "
                f"{Path(next(iter(catalog.values()), Path('robots/motors/x'))).parent} "
                f"(known: {sorted(catalog)}); add robots/motors/{model}.toml"
            )
        hits = [j for j in joints if fnmatch.fnmatchcase(j, pattern)]
        if not hits:
            raise RobotImportError(
                f"--motor '{flag}': pattern '{pattern}' matches no joint of {urdf.name} "
                f"(joints: {joints})"
            )
        for j in hits:
            chosen[j] = model
    for j in joints:
        if j not in chosen:
            raise RobotImportError(
                f"{urdf}: <joint name='{j}'>: no motor model; expected --motor {j}=MODEL "
                f"(or --motor '*=MODEL'; catalog: {sorted(catalog)})"
            )
    return chosen


def import_robot(
    source: str | Path,
    out: str | Path,
    srdf: str | Path | None = None,
    motors: list[str] | tuple[str, ...] = (),
    ee_site: str | None = None,
    limits: list[str] | tuple[str, ...] = (),
    velocities: list[str] | tuple[str, ...] = (),
    control_rate: float = DEFAULT_CONTROL_RATE,
    physics_timestep: float = DEFAULT_PHYSICS_TIMESTEP,
    force: bool = False,
    log=print,
    floating_base: bool = False,
    feet: list[str] | tuple[str, ...] = (),
    imu: str | None = None,
    kp: list[str] | tuple[str, ...] = (),
    kd: list[str] | tuple[str, ...] = (),
    home: list[str] | tuple[str, ...] = (),
    notes: list[str] | tuple[str, ...] = (),
    command: list[str] | None = None,
    unitree: dict | None = None,
) -> ImportReport:
    """Import ``source`` (URDF or MJCF path, or ``PACKAGE:path``) into the robot folder ``out``.

    Args:
        source: The description: a URDF (root ``<robot>``) or an MJCF (root ``<mujoco>``).
        out: The robot folder to create (its name is the robot's).
        srdf: SRDF whose ``disable_collisions`` pairs are not checked (MJCF: added to its
            ``<contact><exclude>`` pairs; else: non-adjacent links that do not touch at the home
            pose). motors: ``JOINT=MODEL`` (shell patterns).
        ee_site: Link (MJCF: body, or one of its sites) carrying the end-effector site (default:
            an MJCF site named ``ee``, else the deepest link of the longest chain). limits:
            ``JOINT=LOWER:UPPER`` (rad) for joints the description leaves unlimited.
            velocities: ``JOINT=RAD_S`` (shell patterns): velocity limits where the description
            has none (MJCF never has one) or to replace its value; the motor's no-load speed
            still caps them. control_rate: Hz. physics_timestep: s (an integer fraction of the
            control period). force: replace an existing ``out``. log: where decisions are
            printed.
        floating_base: A legged robot (:mod:`robots.importer.legged`): free joint, floor, IMU,
            foot spheres with touch sensors, ``[base]`` in robot.toml. feet: foot links (default:
            the last link of each leg). imu: the IMU link (default: a link named ``imu``).
            kp, kd: ``JOINT=VALUE`` (shell patterns) plant PD gains, N m/rad and N m s/rad
            (default: the importer's rule). home: ``JOINT=RAD`` (shell patterns) home pose.
            notes: comment lines for robot.toml's header (the sources of flag values).
            command: the command line printed in robot.toml to regenerate the folder.
            unitree: a Unitree quadruped's ``[unitree]`` table: ``family``, ``damping_kd``,
            ``ramp_kp``, ``ramp_kd`` (:func:`robots.importer.unitree.unitree_lines`). feet, imu,
            kp, kd, home, notes and unitree need ``floating_base``.

    Returns:
        An :class:`ImportReport`.

    Raises:
        RobotImportError: one line naming the file, the element and the expected value
            (continuous or MJCF hinge joint without limits, unresolvable mesh, zero inertia,
            duplicate joint, SRDF naming an unknown link, motor not in the catalog, floating
            base or MJCF free joint without ``floating_base``, no velocity limit from
            description, flag or motor, ...). Nothing is left in ``out``.
    """
    start = time.perf_counter()
    legged_flags = {"--foot": feet, "--imu": imu, "--kp": kp, "--kd": kd, "--home": home}
    legged_flags["--note"] = notes
    legged_flags["--unitree"] = unitree
    used = [k for k, v in legged_flags.items() if v]
    if used and not floating_base:
        raise RobotImportError(f"{', '.join(used)}: only with --floating-base (a legged robot)")
    path = resolve_source(str(source))
    out = Path(out).resolve()
    name = out.name
    if out.exists() and any(out.iterdir()) and not force:
        raise RobotImportError(f"--out {out}: folder exists and is not empty (use --force)")
    srdf_path = resolve_source(str(srdf)) if srdf is not None else None
    limit_overrides = _parse_limits(limits)

    urdf, srdf_info = _prepare(path, srdf_path, limit_overrides, floating_base)
    for note in urdf.notes:
        log(f"note: {note}")
    _apply_velocities(urdf, list(velocities))

    chosen = _assign_motors(path, urdf.movable, list(motors))
    motor_cfg: dict[str, MotorConfig] = {m: load_motor(m) for m in set(chosen.values())}

    report = ImportReport(out=out, joints=list(urdf.movable), notes=list(urdf.notes))
    spec, model = build_spec(urdf, chosen, motor_cfg, physics_timestep)
    joint_names = [model.joint(i).name for i in range(model.njnt)]
    if floating_base:
        from robots.importer.legged import import_floating_base

        import_floating_base(
            path=path, out=out, name=name, urdf=urdf, srdf_info=srdf_info, srdf_path=srdf_path,
            spec=spec, model=model, joint_names=joint_names, chosen=chosen, motor_cfg=motor_cfg,
            report=report, feet=list(feet), imu=imu, kp=list(kp), kd=list(kd), home=list(home),
            notes=list(notes), control_rate=control_rate, physics_timestep=physics_timestep,
            command=command or ["robot-import", str(source), "--out", str(out)], log=log,
            unitree=unitree,
        )  # fmt: skip
        report.seconds = time.perf_counter() - start
        log(f"wrote {out} ({len(joint_names)} joints, floating base) in {report.seconds:.1f} s")
        return report

    ee_body, ee_frame = choose_ee_body(model, urdf, ee_site, path)
    if ee_site is None:
        where = f"at site '{ee_frame}' of" if ee_frame else "on"
        log(
            f"note: end-effector site 'ee' {where} link '{ee_body}' (choose another with --ee-site)"
        )

    limits_out, lowered, notes = cap_limits(urdf, chosen, motor_cfg, log)
    report.lowered += lowered
    report.notes += notes

    with tempfile.TemporaryDirectory(prefix=f".{name}-", dir=out.parent) as tmp:
        work = Path(tmp) / name
        work.mkdir()
        mjcf_path = work / f"{name}.xml"
        _finish_mjcf(spec, ee_body, ee_frame, urdf, mjcf_path)
        # the MJCF writes ranges to 6 significant digits: robot.toml must say the same
        written = mujoco.MjModel.from_xml_path(str(_resolved_mjcf(mjcf_path)))
        for i, j in enumerate(joint_names):
            lo, hi = (float(x) for x in written.jnt_range[i])
            limits_out[j] = (lo, hi, *limits_out[j][2:])
        motion = derive_motion_limits(spec, model, joint_names, limits_out, motor_cfg, chosen)
        home = motion.home
        pairs, excluded, dropped = choose_collision_pairs(
            mjcf_path, model, urdf, srdf_info, home, path
        )
        for a, b, d in dropped:
            log(f"note: links {a} and {b} are {d * 1000:.1f} mm apart at home: pair not checked")
        if excluded:
            _add_contact_excludes(mjcf_path, excluded)
        ws = sample_workspace(mjcf_path, joint_names, limits_out, home)
        write_robot_toml(
            work / "robot.toml",
            name=name,
            prepared=urdf,
            mjcf=mjcf_path.name,
            joint_names=joint_names,
            limits=limits_out,
            motion=motion,
            chosen=chosen,
            motor_cfg=motor_cfg,
            pairs=pairs,
            workspace=ws,
            control_rate=control_rate,
            physics_timestep=physics_timestep,
            disabled_by=_disabled_by(urdf, srdf_path),
            lowered=report.lowered,
        )
        try:
            load_robot(work)
        except RobotSpecError as exc:
            raise RobotImportError(f"{path}: the imported robot does not load: {exc}") from None
        if out.exists():
            shutil.rmtree(out)
        work.rename(out)
    report.seconds = time.perf_counter() - start
    log(f"wrote {out} ({len(joint_names)} joints) in {report.seconds:.1f} s")
    return report


def _prepare(
    path: Path,
    srdf_path: Path | None,
    limit_overrides: dict[str, tuple[float, float]],
    floating_base: bool = False,
) -> tuple[PreparedSource, SrdfInfo | None]:
    """The prepared description and the link pairs left unchecked (SRDF, MJCF excludes)."""
    root = _parse_xml(path)
    if floating_base and root.tag != "robot":
        raise RobotImportError(f"{path}: --floating-base: expected a URDF <robot> (MJCF later)")
    if root.tag == "mujoco":
        source = prepare_mjcf(path, limit_overrides)
        srdf_info = None
        if srdf_path is not None:
            srdf_info = read_srdf(srdf_path, set(source.links), "MJCF")
        if source.disabled or srdf_info is not None:
            disabled = set(source.disabled) | (srdf_info.disabled if srdf_info else set())
            srdf_info = SrdfInfo(path=srdf_path or path, disabled=disabled)
        return source, srdf_info
    if root.tag != "robot":
        raise RobotImportError(
            f"{path}: <{root.tag}>: expected a URDF <robot> or an MJCF <mujoco> root element"
        )
    links = {link.get("name") for link in root.iter("link")}
    srdf_info = (
        read_srdf(srdf_path, links, floating_base=floating_base) if srdf_path is not None else None
    )
    return prepare_urdf(path, root, limit_overrides, srdf_info, floating_base), srdf_info


def _disabled_by(source: PreparedSource, srdf_path: Path | None) -> str | None:
    """What named the unchecked link pairs, for robot.toml's comment (None: nothing did)."""
    named = []
    if srdf_path is not None:
        named.append(f"the SRDF ({Path(srdf_path).name})")
    if source.disabled:
        named.append(f"the MJCF's <contact><exclude> ({source.path.name})")
    return " or ".join(named) or None


def _apply_velocities(source: PreparedSource, flags: list[str]) -> None:
    """Set joint velocity limits from ``--velocity JOINT=RAD_S`` (shell patterns; later win)."""
    for flag in flags:
        pattern, sep, value = flag.partition("=")
        try:
            if not sep or not pattern:
                raise ValueError
            velocity = float(value)
            if not (np.isfinite(velocity) and velocity > 0):
                raise ValueError
        except ValueError:
            raise RobotImportError(
                f"--velocity '{flag}': expected JOINT=RAD_S with a positive limit in rad/s "
                "(JOINT may be a pattern, e.g. '*=3.14')"
            ) from None
        hits = [j for j in source.movable if fnmatch.fnmatchcase(j, pattern)]
        if not hits:
            raise RobotImportError(
                f"--velocity '{flag}': pattern '{pattern}' matches no joint of "
                f"{source.path.name} (joints: {source.movable})"
            )
        for j in hits:
            source.joints[j].velocity = velocity
            source.joints[j].velocity_from = "--velocity"


def _parse_xml(path: Path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise RobotImportError(f"{path}: not valid XML: {exc}") from None


def _parse_limits(flags) -> dict[str, tuple[float, float]]:
    out = {}
    for flag in flags:
        joint, sep, rng = flag.partition("=")
        lo, sep2, hi = rng.partition(":")
        try:
            if not (sep and sep2):
                raise ValueError
            out[joint] = (float(lo), float(hi))
        except ValueError:
            raise RobotImportError(
                f"--limit '{flag}': expected JOINT=LOWER:UPPER in rad (e.g. j1=-3.14:3.14)"
            ) from None
    return out


def _finish_mjcf(spec, ee_body: str, ee_frame: str | None, urdf, mjcf_path: Path) -> None:
    """Add the ``ee`` site (at link ``ee_body``, or at its site ``ee_frame``), write the MJCF
    with the package meshdir placeholder."""
    # The site goes on the nearest body that a joint moves, at the fixed transform of the chosen
    # link: Pinocchio's MJCF parser misplaces sites of joint-less child bodies (0.107 m on panda).
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, ee_body)
    anc = b
    while anc > 0 and model.body_jntnum[anc] == 0:
        anc = model.body_parentid[anc]
    if ee_frame is None:
        target_pos, target_quat = data.xpos[b], data.xquat[b]
    else:
        s = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, ee_frame)
        target_pos, target_quat = data.site_xpos[s], np.zeros(4)
        mujoco.mju_mat2Quat(target_quat, data.site_xmat[s])
    rot = data.xmat[anc].reshape(3, 3)
    pos = rot.T @ (target_pos - data.xpos[anc])
    quat = np.zeros(4)
    inv = np.zeros(4)
    mujoco.mju_negQuat(inv, data.xquat[anc])
    mujoco.mju_mulQuat(quat, inv, target_quat)
    old = spec.site("ee")
    if old is not None:  # an MJCF's own 'ee' site: replaced by the one placed here
        spec.delete(old)
    spec.body(model.body(anc).name).add_site(
        name="ee", size=[0.005, 0.005, 0.005], pos=pos, quat=quat
    )
    spec.compile()
    xml = spec.to_xml()
    if urdf.meshdir_abs is not None:
        xml = xml.replace(f'meshdir="{urdf.meshdir_abs}"', f'meshdir="{urdf.meshdir_uri}"', 1)
        if urdf.meshdir_uri.startswith(PACKAGE_SCHEME) and urdf.meshdir_uri not in xml:
            raise RobotImportError(f"{mjcf_path}: <compiler meshdir>: could not be written")
    header = (
        f"<!-- Generated by robot-import from {urdf.display} with MuJoCo's {urdf.kind} compiler "
        "(mujoco.MjSpec). Radians, explicit inertials, no actuators (Robot.mjspec adds them per "
        "control mode). Meshes are read from the installed package named by meshdir. -->\n"
    )
    mjcf_path.write_text(header + xml, encoding="utf-8")


def _add_contact_excludes(mjcf_path: Path, excluded: list[tuple[str, str]]) -> None:
    tree = ET.parse(mjcf_path)
    root = tree.getroot()
    contact = root.find("contact")
    if contact is None:
        contact = ET.SubElement(root, "contact")
    for a, b in excluded:
        ET.SubElement(contact, "exclude", body1=a, body2=b)
    ET.indent(tree, "  ")
    text = ET.tostring(root, encoding="unicode")
    head = mjcf_path.read_text(encoding="utf-8").split("\n", 1)[0]
    mjcf_path.write_text(head + "\n" + text + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="robot-import",
        description=__doc__.split("::")[0].strip(),
        epilog=f"Motor models in the catalog: {', '.join(sorted(motor_catalog()))}",
    )
    p.add_argument("source", help="URDF or MJCF file, or PACKAGE:path (example-robot-data:...)")
    p.add_argument("--out", required=True, help="robot folder to write (its name = robot name)")
    p.add_argument("--srdf", default=None, help="SRDF with disable_collisions pairs")
    p.add_argument(
        "--motor",
        action="append",
        default=[],
        metavar="JOINT=MODEL",
        help="motor model of a joint (shell pattern, '*' = every joint); repeatable",
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
        help="position limits (rad) for a continuous joint the description leaves unlimited",
    )
    p.add_argument(
        "--velocity",
        action="append",
        default=[],
        metavar="JOINT=RAD_S",
        help="velocity limit (rad/s) where the description has none (MJCF) or to replace it; "
        "shell pattern; the motor's no-load speed still caps it; repeatable",
    )
    p.add_argument("--control-rate", type=float, default=DEFAULT_CONTROL_RATE, help="Hz")
    p.add_argument("--physics-timestep", type=float, default=DEFAULT_PHYSICS_TIMESTEP, help="s")
    p.add_argument("--force", action="store_true", help="replace an existing --out folder")
    legged = p.add_argument_group("floating-base (legged) robots")
    legged.add_argument(
        "--floating-base",
        action="store_true",
        help="a legged robot: free joint, floor, IMU and foot contact sensors",
    )
    legged.add_argument("--foot", action="append", default=[], metavar="LINK", help="a foot link")
    legged.add_argument("--imu", default=None, metavar="LINK", help="the IMU link")
    for flag, unit in (("--kp", "N m/rad"), ("--kd", "N m s/rad"), ("--home", "rad")):
        legged.add_argument(
            flag,
            action="append",
            default=[],
            metavar="JOINT=VALUE",
            help=f"{flag[2:]} ({unit}) of joints (shell pattern); repeatable",
        )
    legged.add_argument(
        "--note", action="append", default=[], help="a comment line for robot.toml's header"
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
    args = p.parse_args(argv)
    unitree = None
    if args.unitree is not None:
        if args.unitree_damping_kd is None:
            print("robot-import: error: --unitree needs --unitree-damping-kd", file=sys.stderr)
            return EXIT_REFUSED
        unitree = {
            "family": args.unitree,
            "damping_kd": args.unitree_damping_kd,
            "ramp_kp": args.unitree_ramp_kp,
            "ramp_kd": args.unitree_ramp_kd,
        }
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
            floating_base=args.floating_base,
            feet=args.foot,
            imu=args.imu,
            kp=args.kp,
            kd=args.kd,
            home=args.home,
            notes=args.note,
            command=["robot-import", *(sys.argv[1:] if argv is None else argv)],
            unitree=unitree,
        )
    except RobotImportError as exc:
        print(f"robot-import: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
