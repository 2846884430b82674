"""Floating-base (legged) robots for the importer: ``robot-import ... --floating-base``.

After the steps every import shares (:func:`sim2real.robots.importer.model.build_spec`, motor limits), a
floating-base robot gets the free joint, floor, IMU and feet of
:func:`sim2real.robots.importer.floating_mjcf.finish_floating_mjcf` in its MJCF, its collision pairs
(``LEG_CLEARANCE``) and a robot.toml (:func:`write_legged_toml`).

robot.toml (:func:`write_legged_toml`) then has a ``[base]`` table, ``[sensors.imu]`` and
``[sensors.contact]`` with the defaults below (each with its source), no workspace box and no
task region (velocity commands are a later issue).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from sim2real.robots.importer.floating_mjcf import IMU_SITE, finish_floating_mjcf
from sim2real.robots.importer.foot_sites import foot_with_geometry
from sim2real.robots.importer.legged_toml import write_legged_toml
from sim2real.robots.importer.model import SOFT_LIMIT_FRACTION, Motion, _sig
from sim2real.robots.importer.source import PreparedSource, RobotImportError
from sim2real.robots.importer.wheels import check_velocity_drives, wheel_joints
from sim2real.robots.packages import resolved_mjcf

#: Link pairs closer than this at the home pose (m) are not checked and never collide in the
#: plant: the importer's bounding boxes of neighbouring legs' links (the rear hips of go2 are
#: 1-2 mm apart and touch as soon as the legs carry the body) overlap where the meshes do not.
LEG_CLEARANCE = 0.01


def choose_feet(prepared: PreparedSource, flags: list[str]) -> list[str]:
    """Foot links: ``--foot LINK`` flags in order, else the leaf links with the most movable
    joints above them (each leg's last link), in file order.

    Raises:
        RobotImportError: a flag naming no link, or fewer than two feet found.
    """
    if flags:
        for link in flags:
            if link not in prepared.links:
                raise RobotImportError(
                    f"--foot {link}: not a link of {prepared.path.name} (links: {prepared.links})"
                )
        return list(flags)
    children = {par for par, _, _ in prepared.parent.values()}

    def movable(link: str) -> int:
        count = 0
        while link in prepared.parent:
            par, _, kind = prepared.parent[link]
            count += kind != "fixed"
            link = par
        return count

    leaves = [x for x in prepared.links if x not in children and x != prepared.root_link]
    depth = max((movable(x) for x in leaves), default=0)
    feet = [x for x in leaves if movable(x) == depth and depth > 0]
    if len(feet) < 2:
        raise RobotImportError(
            f"{prepared.path}: found feet {feet}; expected two or more legs (name the foot links "
            "with --foot LINK)"
        )
    return feet


def choose_imu(prepared: PreparedSource, flag: str | None, log) -> tuple[str, str | None]:
    """The IMU: ``(link, site or None)``: ``--imu LINK`` or (MJCF) ``--imu SITE``, else a site
    named ``imu``, else a link named ``imu``, else the root link. The IMU must ride on the base
    (the root link, or a link fixed to it): the runtime estimates the base from it; a default
    elsewhere falls back to the root link, with a note.

    Raises:
        RobotImportError: ``--imu`` names neither a link nor a site, or one a joint moves
            relative to the base.
    """
    if flag is not None:
        flag = prepared.renamed_sites.get(flag, flag)  # a site named like its body, renamed
        if flag in prepared.sites:
            link, site = prepared.sites[flag], flag
        elif flag in prepared.links:
            link, site = flag, None
        else:
            sites = f", sites: {sorted(prepared.sites)}" if prepared.sites else ""
            raise RobotImportError(
                f"--imu {flag}: not a link{' or site' if sites else ''} of {prepared.path.name} "
                f"(links: {prepared.links}{sites})"
            )
        joint = _joint_to_base(prepared, link)
        if joint is not None:
            raise RobotImportError(
                f"--imu {flag}: on link {link}, which joint '{joint}' moves relative to the base "
                f"{prepared.root_link}; expected the base or a link fixed to it (the runtime "
                "estimates the base from the IMU)"
            )
        return link, site
    imu_site = prepared.renamed_sites.get(IMU_SITE, IMU_SITE)
    if imu_site in prepared.sites:
        link = prepared.sites[imu_site]
        joint = _joint_to_base(prepared, link)
        if joint is None:
            return link, imu_site
        log(
            f"note: site '{IMU_SITE}' is on link {link}, which joint '{joint}' moves: the IMU "
            f"site is at the root link {prepared.root_link} (--imu names another)"
        )
        return prepared.root_link, None
    if "imu" in prepared.links and _joint_to_base(prepared, "imu") is None:
        return "imu", None
    root = prepared.root_link
    log(f"note: no link named 'imu' on the base: the IMU site is at the root link {root}")
    return prepared.root_link, None


def _joint_to_base(prepared: PreparedSource, link: str) -> str | None:
    """The first joint between ``link`` and the root link that moves, or None (fixed to it)."""
    while link in prepared.parent:
        par, joint, kind = prepared.parent[link]
        if kind != "fixed":
            return joint
        link = par
    return None


def robot_mass(mjcf_path: Path) -> float:
    """Total mass (kg) of the robot in ``mjcf_path`` (MuJoCo, resolved meshdir)."""
    model = mujoco.MjModel.from_xml_path(str(resolved_mjcf(mjcf_path)))
    return float(model.body_subtreemass[0])


#: Jerk limit of a PD target per unit of its acceleration limit, in control periods: the full
#: acceleration is reached within half a period (our choice, with ``pd_target_limits``).
PD_JERK_PERIODS = 0.5


def pd_target_limits(
    effort: np.ndarray, kp: np.ndarray, period: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Velocity (rad/s), acceleration (rad/s^2) and jerk (rad/s^3) limits, (n,), that let a PD
    position target move, rest to rest within one control period, as far as the drive's full
    torque reaches.

    A legged policy's position target is a torque in disguise: the drive applies
    ``kp (target - q) - kd dq``, so a target ``effort / kp`` from the joint asks for the full
    torque, and policies trained without a smoother (legged_gym, Isaac Lab, mjlab) step their
    targets that far from one control period to the next. A rest-to-rest move of ``d`` in time
    ``T`` with acceleration ``a`` needs ``a = 4 d / T^2`` and reaches ``v = 2 d / T``; the jerk
    reaches ``a`` within ``PD_JERK_PERIODS`` of a period. Limits below these make the smoother,
    not the policy, decide how the legs move: the policy falls where it walks in its own loop.
    The velocity is the target's, not the joint's: the joint's own limit (the motor's no-load
    speed) still bounds what the guard and the monitors accept of the joint.

    Args:
        effort: (n,) N m, the joints' effort limits. kp: (n,) N m/rad, the drives' gains.
        period: s, the control period.
    """
    reach = np.asarray(effort, dtype=np.float64) / np.asarray(kp, dtype=np.float64)
    vel = 2.0 * reach / period
    acc = 4.0 * reach / period**2
    jerk = acc / (PD_JERK_PERIODS * period)
    return tuple(np.array([_sig(x) for x in values]) for values in (vel, acc, jerk))


def import_floating_base(
    job,
    *,
    feet: list[str],
    imu: str | None,
    kp: list[str],
    kd: list[str],
    home: list[str],
    notes: list[str],
    command: list[str],
    target_limits: str = "pd",
    unitree: dict | None = None,
    policy: tuple[dict, str] | None = None,
) -> None:
    """The floating-base half of :func:`sim2real.robots.importer.pipeline.import_robot`: ``job`` is a
    :class:`sim2real.robots.importer.staging.ImportJob`, the rest its floating-base arguments;
    ``policy``: the ``--drive-from`` policy's (quantity -> joint -> value, source). Each joint's
    kp, kd and home come from the flags, the policy, the robot file or the importer's rule
    (:mod:`sim2real.robots.importer.drive_sources`), each source printed.

    Raises:
        RobotImportError: see :func:`choose_feet`, :func:`choose_imu`,
            :func:`finish_floating_mjcf`, a bad ``--kp``/``--kd``/``--home`` flag or a home
            pose outside the limits, or a result that does not load.
    """
    from sim2real.robots.importer.contact_pairs import write_pairs
    from sim2real.robots.importer.staging import written_ranges

    urdf, spec, joint_names, log = job.urdf, job.spec, job.joint_names, job.log
    foot_links, (imu_link, imu_site) = _feet_and_imu(job, feet, imu)
    tables = []
    if unitree is not None:
        from sim2real.robots.importer.unitree import unitree_lines

        tables = unitree_lines(joint_names=joint_names, feet=foot_links, **unitree)
    limits_out = job.capped_limits()
    drive, wheels = _drive(job, kp, kd, home, policy, limits_out)
    motion = _motion(job, drive, limits_out, wheels, target_limits)
    gains_from = {j: drive.gains_note(j) for j in joint_names}
    home_from = _home_from(drive, joint_names)
    with job.staged() as (work, mjcf_path):
        legged = finish_floating_mjcf(
            spec, urdf, foot_links, (imu_link, imu_site), joint_names, motion.home, mjcf_path
        )
        write_pairs(mjcf_path, urdf, log)  # the MJCF's <contact><pair>s, the floor named
        for foot, shape in legged["foot_shapes"].items():
            log(f"note: foot {foot}: {shape}")
        for line in legged["notes"]:
            log(f"note: {line}")
        # the model's joint 0 is the free joint
        written = written_ranges(mjcf_path, joint_names, limits_out, first=1)
        motion = _motion(job, drive, limits_out, wheels, target_limits)
        pairs = job.collision_pairs(mjcf_path, written, motion.home, LEG_CLEARANCE)
        write_legged_toml(
            work / "robot.toml",
            gains_from=gains_from,
            legged=legged,
            imu_link=imu_link,
            mass=robot_mass(mjcf_path),
            home_from=home_from,
            notes=notes,
            command=command,
            target_limits=target_limits,
            tables=tables,
            **job.toml_args(mjcf_path, limits_out, motion, pairs),
        )


def _feet_and_imu(job, feet: list[str], imu: str | None) -> tuple[list[str], tuple]:
    """The foot links (each the link carrying its geometry) and ``(imu link, MJCF site or
    None)``, each choice printed."""
    foot_links = []
    for foot in choose_feet(job.urdf, feet):
        link, note = foot_with_geometry(job.spec, job.urdf, foot)
        foot_links.append(link)
        if note:
            job.log(f"note: {note}")
    imu_link, imu_site = choose_imu(job.urdf, imu, job.log)
    at = f"site {imu_site} of link {imu_link}" if imu_site else f"link {imu_link}"
    job.log(f"note: feet {foot_links}, IMU at {at}")
    return foot_links, (imu_link, imu_site)


def _drive(job, kp: list[str], kd: list[str], home: list[str], policy, limits_out: dict):
    """``(drive, wheels)``: each joint's kp, kd and home with its source
    (:func:`sim2real.robots.importer.drive_sources.choose`, the sources printed), and the wheel
    joints (kp 0 there: a velocity drive).

    Raises:
        RobotImportError: a bad flag, or a negative gain (kp 0 only on a wheel).
    """
    from sim2real.robots.importer import flags
    from sim2real.robots.importer.drive_sources import choose, source_lines

    joint_names = job.joint_names
    expected = "JOINT=VALUE with a finite number (JOINT may be a pattern, e.g. '*_knee_joint=0.3')"
    home_set, kp_set, kd_set = (
        flags.per_joint(values, joint_names, flag, flags.finite, expected, job.urdf.path.name)
        for flag, values in (("--home", home), ("--kp", kp), ("--kd", kd))
    )
    wheels = wheel_joints(joint_names, limits_out)
    for flag, values in (("--kp", kp_set), ("--kd", kd_set)):
        bad = {j: v for j, v in values.items() if v < 0 or (flag == "--kp" and v == 0)}
        bad = {j: v for j, v in bad.items() if not (flag == "--kp" and v == 0 and j in wheels)}
        if bad:
            raise RobotImportError(
                f"{flag}: gains must be positive (kd may be 0, kp 0 on a continuous joint), "
                f"got {bad}"
            )
    drive = choose(
        joint_names, {"kp": kp_set, "kd": kd_set, "home": home_set}, policy, job.urdf.drive
    )
    for line in source_lines(drive, joint_names):
        job.log(f"note: {line}")
    return drive, wheels


def _motion(job, drive, limits_out: dict, wheels, target_limits: str) -> Motion:
    """The joints' motion limits from the model as it stands (``job.model``), with the drive's
    home, kp and kd; PD targets' limits widened (:func:`pd_target_limits`).

    Raises:
        RobotImportError: a home angle outside its joint's limits.
    """
    from sim2real.robots.importer.model import LEGGED_MAX_ACCELERATION, derive_motion_limits

    joint_names = job.joint_names
    motion = derive_motion_limits(
        job.spec, job.model, joint_names, limits_out, job.motor_cfg, job.chosen,
        LEGGED_MAX_ACCELERATION,
    )  # fmt: skip
    for i, j in enumerate(joint_names):
        motion.home[i] = drive.values["home"].get(j, motion.home[i])
        motion.kp[i] = drive.values["kp"].get(j, motion.kp[i])
        motion.kd[i] = drive.values["kd"].get(j, motion.kd[i])
        lo, hi = limits_out[j][:2]
        if not lo <= motion.home[i] <= hi:
            raise RobotImportError(
                f"home pose ({drive.sources['home'][j]}): joint {j} at {motion.home[i]} rad "
                f"is outside its limits [{lo}, {hi}]"
            )
    speed = check_velocity_drives(joint_names, motion.kp, wheels, drive.sources["kp"])
    if target_limits == "pd":  # a velocity drive (kp 0) takes no PD target
        effort = np.array([limits_out[j][3] for j in joint_names])
        kp_pd = np.where(speed, np.inf, motion.kp)
        vel, acc, jerk = pd_target_limits(effort, kp_pd, 1.0 / job.control_rate)
        soft = SOFT_LIMIT_FRACTION * np.array([limits_out[j][2] for j in joint_names])
        motion.command_velocity = np.maximum(soft, vel)
        motion.acceleration[:] = np.maximum(motion.acceleration, acc)
        motion.jerk[:] = np.maximum(motion.jerk, jerk)
    return motion


def _home_from(drive, joint_names: list[str]) -> str:
    """Where the home pose came from, for robot.toml's comment."""
    from sim2real.robots.importer.drive_sources import RULE, source_lines

    return "; ".join(
        line.removeprefix("home: ")
        .removesuffix(" (every joint)")
        .replace(RULE, "0 clipped into the soft limits")
        for line in source_lines(drive, joint_names)
        if line.startswith("home: ")
    )
