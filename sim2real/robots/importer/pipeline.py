"""Import a robot from its published description (URDF, or MJCF) into a robot folder:
:func:`import_robot`, the function behind ``robot-import`` (its command line:
:mod:`sim2real.deploy.cli.robot_import`).
It writes ``<out>/<name>.xml`` (MJCF made by MuJoCo's own URDF or MJCF compiler through
``mujoco.MjSpec``: radians, explicit inertials, no actuators, one ``ee`` site) and
``<out>/robot.toml`` (joint order and limits from the description, capped by the motors'
capabilities; motors from the catalog ``sim2real/robots/motors/``; sensors from the motors; collision
pairs; home pose; task region). Meshes are never copied: the MJCF's ``meshdir`` names the
installed package (``package://...``) and :func:`robots.load_robot` resolves it. Every output is
checked with :func:`robots.load_robot` (MuJoCo/Pinocchio agreement) before it is moved into
place: a failed import leaves nothing.

The source is a URDF (root ``<robot>``, :mod:`sim2real.robots.importer.urdf`) or an MJCF (root
``<mujoco>``, :mod:`sim2real.robots.importer.mjcf`); both become a
:class:`sim2real.robots.importer.source.PreparedSource`, and everything after that is the same code.
The per-joint flags (shell patterns, motors from the catalog or from a file) are read by
:mod:`sim2real.robots.importer.flags`; the model steps (limits, gains, pairs, workspace) are in
:mod:`sim2real.robots.importer.model`; an arm is finished by :mod:`sim2real.robots.importer.fixed_base`, a
legged robot (``--floating-base``) by :mod:`sim2real.robots.importer.legged` (its MJCF:
:mod:`sim2real.robots.importer.floating_mjcf`); robot.toml's text is
:mod:`sim2real.robots.importer.toml_text`. Errors (:class:`RobotImportError`, exit code 3) are one line naming
the file, the element and what was expected.
"""

from __future__ import annotations

import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from sim2real.robots.importer import flags, mjcf_geoms
from sim2real.robots.importer.fixed_base import import_fixed_base
from sim2real.robots.importer.mjcf import prepare_mjcf
from sim2real.robots.importer.model import build_spec
from sim2real.robots.importer.physics_option import choose_timestep
from sim2real.robots.importer.source import PreparedSource, RobotImportError, SrdfInfo, read_srdf
from sim2real.robots.importer.staging import ImportJob
from sim2real.robots.importer.urdf import prepare_urdf
from sim2real.robots.packages import package_root
from sim2real.robots.robot import RobotSpecError

__all__ = ["ImportReport", "RobotImportError", "import_robot", "resolve_source"]

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


def import_robot(
    source: str | Path,
    out: str | Path,
    srdf: str | Path | None = None,
    motors: list[str] | tuple[str, ...] = (),
    ee_site: str | None = None,
    limits: list[str] | tuple[str, ...] = (),
    velocities: list[str] | tuple[str, ...] = (),
    control_rate: float | None = None,
    physics_timestep: float | None = None,
    force: bool = False,
    log=print,
    drop_missing_meshes: bool = False,
    link_boxes: bool = False,
    floating_base: bool = False,
    feet: list[str] | tuple[str, ...] = (),
    imu: str | None = None,
    kp: list[str] | tuple[str, ...] = (),
    kd: list[str] | tuple[str, ...] = (),
    home: list[str] | tuple[str, ...] = (),
    notes: list[str] | tuple[str, ...] = (),
    target_limits: str = "pd",
    command: list[str] | None = None,
    unitree: dict | None = None,
    mesh_boxes: bool = False,
    drive=None,
    options: list[str] | tuple[str, ...] = (),
    keyframe: str | None = None,
) -> ImportReport:
    """Import ``source`` (URDF or MJCF path, or ``PACKAGE:path``) into the robot folder ``out``.

    Args:
        source: The description: a URDF (root ``<robot>``) or an MJCF (root ``<mujoco>``).
        out: The robot folder to create (its name is the robot's).
        srdf: SRDF whose ``disable_collisions`` pairs are not checked (MJCF: added to its
            ``<contact><exclude>`` pairs; else: non-adjacent links that do not touch at the home
            pose). motors: ``JOINT=MODEL`` (shell patterns; MODEL a catalog model or the path of
            a motor TOML file, whose table robot.toml then holds).
        ee_site: Link (MJCF: body, or one of its sites) carrying the end-effector site (default:
            an MJCF site named ``ee``, else the deepest link of the longest chain). limits:
            ``JOINT=LOWER:UPPER`` (rad, shell patterns) for joints the description leaves
            unlimited, or to replace their range.
            velocities: ``JOINT=RAD_S`` (shell patterns): velocity limits where the description
            has none (MJCF never has one) or to replace its value; the motor's no-load speed
            still caps them. control_rate: Hz. physics_timestep: s (an integer fraction of the
            control period; None: the MJCF's ``<option timestep>``, else 0.002). force:
            replace an existing ``out``. log: where decisions are printed.
            drop_missing_meshes: drop the geoms (URDF: the elements) whose mesh file is
            missing, each printed, instead of refusing. link_boxes: one bounding box per link
            around all its collision meshes (what robot-import wrote before one box per mesh;
            coarser, fewer collision pairs) instead of one box per mesh.
        floating_base: A legged robot (:mod:`sim2real.robots.importer.legged`): free joint (an MJCF's own
            free joint is replaced), floor, IMU, foot sites with touch sensors, ``[base]`` in
            robot.toml. feet: foot links (default: the last link of each leg). imu: the IMU link,
            or an MJCF site (default: a site or a link named ``imu``, else the root link).
            kp, kd: ``JOINT=VALUE`` (shell patterns) plant PD gains, N m/rad and N m s/rad
            (default: the importer's rule). home: ``JOINT=RAD`` (shell patterns) home pose.
            notes: comment lines for robot.toml's header (the sources of flag values).
            command: the command line printed in robot.toml to regenerate the folder.
            target_limits: ``"pd"`` or ``"motion"``, the rule of a legged robot's acceleration
            and jerk limits (:func:`sim2real.robots.importer.legged.pd_target_limits`).
            unitree: a Unitree quadruped's ``[unitree]`` table: ``family``, ``damping_kd``,
            ``ramp_kp``, ``ramp_kd`` (:func:`sim2real.robots.importer.unitree.unitree_lines`). feet, imu,
            kp, kd, home, notes and unitree need ``floating_base``. mesh_boxes: an MJCF's
            collision meshes become their bounding boxes, not their convex hulls
            (:data:`sim2real.robots.importer.mjcf_geoms.MESH_COLLISION`).
            drive: A policy's drive (``robot-import --drive-from POLICY``):
            ``drive(joints, depth, slots)`` with the description's joints, their depths in
            the kinematic tree and each joint's Unitree motor slot (None without ``unitree``) returns an
            object with ``kp``, ``kd``, ``home`` (one value per joint, or None), ``control_rate``
            (Hz or None) and ``source`` (:func:`sim2real.deploy.spec.foreign.drive.policy_drive`); its
            values come before the ``kp``/``kd``/``home`` flags (which win), and its control rate
            is used when ``control_rate`` is None. Needs ``floating_base``.
            control_rate: Hz; None: the drive's, else :data:`DEFAULT_CONTROL_RATE`.
            options: ``KEY=VALUE`` MuJoCo ``<option>`` settings (integrator, iterations,
            ls_iterations, ...) over the MJCF's own (:mod:`sim2real.robots.importer.physics_option`).
            keyframe: the MJCF ``<key>`` whose pose is home where no flag or policy gives it
            (None: ``home``, else the first; :mod:`sim2real.robots.importer.mjcf_drive`); an
            MJCF's ``<position>`` gains likewise come before the importer's rule. Needs
            ``floating_base``.

    The parent folders of ``out`` are created when missing (as ``mkdir -p``; removed again when
    the import fails).

    Returns:
        An :class:`ImportReport`.

    Raises:
        RobotImportError: one line naming the file, the element and the expected value
            (continuous or MJCF hinge joint without limits, unresolvable mesh, zero inertia,
            duplicate joint, SRDF naming an unknown link, motor not in the catalog, floating
            base or MJCF free joint without ``floating_base``, no velocity limit from
            description, flag or motor, a flag pattern matching no joint, ``out`` or a parent
            of it being a file, ...). Nothing is left in ``out``.
    """
    out = Path(out).expanduser().resolve()
    created = _make_parents(out)
    try:
        with mjcf_geoms.mesh_collision("box" if mesh_boxes else mjcf_geoms.MESH_COLLISION):
            return _import(
                source, out, srdf, motors, ee_site, limits, velocities, control_rate,
                physics_timestep, force, log, drop_missing_meshes, link_boxes, floating_base,
                feet, imu, kp, kd, home, notes, command, target_limits, unitree, drive, options,
                keyframe,
            )  # fmt: skip
    except BaseException:
        for folder in created:  # deepest first
            try:
                folder.rmdir()
            except OSError:
                break
        raise


def _make_parents(out: Path) -> list[Path]:
    """Create the missing parent folders of ``out``; return them, deepest first.

    Raises:
        RobotImportError: ``out`` or one of its parents exists and is not a folder.
    """
    for folder in (out, *out.parents):
        if folder.exists() and not folder.is_dir():
            raise RobotImportError(f"--out {out}: {folder} exists and is not a folder")
    missing = [p for p in out.parents if not p.exists()]
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RobotImportError(f"--out {out}: cannot create {out.parent}: {exc}") from None
    return missing


def _import(
    source,
    out: Path,
    srdf,
    motors,
    ee_site,
    limits,
    velocities,
    control_rate,
    physics_timestep,
    force,
    log,
    drop_missing_meshes,
    link_boxes,
    floating_base,
    feet,
    imu,
    kp,
    kd,
    home,
    notes,
    command,
    target_limits="pd",
    unitree=None,
    drive=None,
    options=(),
    keyframe=None,
) -> ImportReport:
    """:func:`import_robot` once the parents of ``out`` exist (its arguments)."""
    start = time.perf_counter()
    legged_flags = {"--foot": feet, "--imu": imu, "--kp": kp, "--kd": kd, "--home": home}
    legged_flags["--drive-from"] = drive
    legged_flags["--note"] = notes
    legged_flags["--unitree"] = unitree
    legged_flags["--keyframe"] = keyframe
    used = [k for k, v in legged_flags.items() if v]
    if used and not floating_base:
        raise RobotImportError(f"{', '.join(used)}: only with --floating-base (a legged robot)")
    path = resolve_source(str(source))
    name = out.name
    if out.exists() and any(out.iterdir()) and not force:
        raise RobotImportError(f"--out {out}: folder exists and is not empty (use --force)")
    srdf_path = resolve_source(str(srdf)) if srdf is not None else None

    urdf, srdf_info = _prepare(
        path, srdf_path, list(limits), floating_base, drop_missing_meshes, link_boxes, keyframe
    )
    for note in urdf.notes:
        log(f"note: {note}")
    _apply_velocities(urdf, list(velocities))

    chosen, motor_cfg, motor_tables = flags.assign_motors(path, urdf.movable, list(motors))
    for motor, (file, _) in sorted(motor_tables.items()):  # not `name`: the robot's (--out)
        if motor_cfg[motor].position_target is None:
            log(
                f"note: motor file {file}: no [position_target]: its drive takes any position "
                "target (the plant clamps none, as a Unitree motor's PD law); add "
                "[position_target] clamped = true with its source where the drive clamps "
                "targets to the joint's range"
            )

    report = ImportReport(out=out, joints=list(urdf.movable), notes=list(urdf.notes))
    physics_timestep, timestep_from = choose_timestep(
        path, physics_timestep, DEFAULT_PHYSICS_TIMESTEP
    )
    spec, model = build_spec(urdf, chosen, motor_cfg, physics_timestep, options)
    log(f"note: {urdf.physics}; timestep {physics_timestep:g} s ({timestep_from})")
    joint_names = [model.joint(i).name for i in range(model.njnt)]
    policy = None
    rate_from = "--control-rate" if control_rate is not None else "the importer's default"
    if drive is not None:  # robot.toml's header says where the control rate came from
        rate_given = control_rate is not None
        policy, control_rate = _policy_drive(drive, model, joint_names, unitree, control_rate, log)
        if control_rate is not None and not rate_given:
            notes = [*notes, f"control rate: the policy's (--drive-from: {policy[1]})"]
            rate_from = "the policy's: --drive-from, see the notes above"
    control_rate = DEFAULT_CONTROL_RATE if control_rate is None else control_rate
    steps = 1.0 / (control_rate * physics_timestep)
    if timestep_from == "the MJCF" and abs(steps - round(steps)) > 1e-6 * steps:
        raise RobotImportError(
            f"{path}: <option timestep='{physics_timestep:g}'>: not a divisor of the control "
            f"period 1/{control_rate:g} s; expected --physics-timestep S (s) that divides it"
        )
    job = ImportJob(
        path=path, out=out, name=name, urdf=urdf, srdf_info=srdf_info, srdf_path=srdf_path,
        spec=spec, model=model, joint_names=joint_names, chosen=chosen, motor_cfg=motor_cfg,
        motor_tables=motor_tables, report=report, control_rate=control_rate,
        physics_timestep=physics_timestep, log=log, rates_from=(rate_from, timestep_from),
    )  # fmt: skip
    if floating_base:
        from sim2real.robots.importer.legged import import_floating_base

        import_floating_base(
            job, feet=list(feet), imu=imu, kp=list(kp), kd=list(kd), home=list(home),
            notes=list(notes), target_limits=target_limits,
            command=command or ["robot-import", str(source), "--out", str(out)], unitree=unitree,
            policy=policy,
        )  # fmt: skip
        report.seconds = time.perf_counter() - start
        log(f"wrote {out} ({len(joint_names)} joints, floating base) in {report.seconds:.1f} s")
        return report

    import_fixed_base(job, ee_site=ee_site)
    report.seconds = time.perf_counter() - start
    log(f"wrote {out} ({len(joint_names)} joints) in {report.seconds:.1f} s")
    return report


def _policy_drive(drive, model, joints, unitree, control_rate, log):
    """``(policy, control_rate)``: the policy's drive as ``(quantity -> joint -> value, source)``
    (:func:`sim2real.robots.importer.drive_sources.choose` puts the flags before it) and the
    control rate (the policy's when ``control_rate`` is None).

    Raises:
        RobotImportError: the drive cannot be read (its one-line message), or ``control_rate``
            differs from the policy's.
    """
    from sim2real.robots.importer.unitree import motor_slots

    depth = []
    for j in range(model.njnt):
        body, d = int(model.jnt_bodyid[j]), 0
        while body:
            body, d = int(model.body_parentid[body]), d + 1
        depth.append(d)
    slots = None if unitree is None else motor_slots(unitree["family"], joints)
    try:
        d = drive(joints, depth, slots)
    except ValueError as exc:  # ForeignFormatError: one line naming the file and the key
        raise RobotImportError(f"--drive-from: {exc}") from None
    rate = d.control_rate
    if control_rate is not None and rate is not None and abs(control_rate - rate) > 1e-9:
        raise RobotImportError(
            f"--control-rate {control_rate:g} Hz: the policy ({d.source}) runs at {rate:g} Hz"
        )
    values = {"kp": d.kp, "kd": d.kd, "home": d.home}
    got = [k for k, v in values.items() if v is not None]
    lacks = [k for k, v in values.items() if v is None] + (["control rate"] if rate is None else [])
    log(
        f"note: --drive-from {d.source}: {', '.join(got) or 'no gain or pose'} read"
        + (f"; it does not record {', '.join(lacks)}" if lacks else "")
    )
    for line in getattr(d, "missing", ()):
        log(f"note: --drive-from: missing {line}")
    per_joint = {k: dict(zip(joints, v, strict=True)) for k, v in values.items() if v is not None}
    return (per_joint, d.source), (control_rate if control_rate is not None else rate)


def _prepare(
    path: Path,
    srdf_path: Path | None,
    limit_flags: list[str],
    floating_base: bool = False,
    drop_missing_meshes: bool = False,
    link_boxes: bool = False,
    keyframe: str | None = None,
) -> tuple[PreparedSource, SrdfInfo | None]:
    """The prepared description and the link pairs left unchecked (SRDF, MJCF excludes).

    Raises:
        RobotImportError: (besides the readers') ``keyframe`` for a URDF, which has none.
    """
    root = _parse_xml(path)
    if keyframe is not None and root.tag != "mujoco":
        raise RobotImportError(f"--keyframe {keyframe}: {path} is not an MJCF (no <keyframe>)")
    if root.tag == "mujoco":
        source = prepare_mjcf(
            path, limit_flags, floating_base, drop_missing_meshes, link_boxes, keyframe
        )
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
    prepared = prepare_urdf(
        path, root, limit_flags, srdf_info, floating_base, drop_missing_meshes, link_boxes
    )
    return prepared, srdf_info


def _apply_velocities(source: PreparedSource, flag_texts: list[str]) -> None:
    """Set joint velocity limits from ``--velocity JOINT=RAD_S`` (shell patterns; later win)."""
    values = flags.per_joint(
        flag_texts,
        source.movable,
        "--velocity",
        flags.positive,
        "JOINT=RAD_S with a positive limit in rad/s (JOINT may be a pattern, e.g. '*=3.14')",
        source.path.name,
    )
    for j, velocity in values.items():
        source.joints[j].velocity = velocity
        source.joints[j].velocity_from = "--velocity"


def _parse_xml(path: Path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise RobotImportError(f"{path}: not valid XML: {exc}") from None
