"""The fixed-base half of robot-import (:func:`import_fixed_base`): an arm's end-effector site,
collision pairs, motion limits, workspace and task box, and its robot.toml, written to a
temporary folder, checked with :func:`robots.load_robot` and moved into place."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from robots.importer.contact_pairs import write_pairs
from robots.importer.model import choose_ee_body, derive_motion_limits, sample_workspace
from robots.importer.source import PreparedSource, RobotImportError
from robots.importer.staging import capped_limits, collision_pairs, staged, written_ranges
from robots.importer.toml_text import write_robot_toml
from robots.packages import PACKAGE_SCHEME


def import_fixed_base(
    *,
    path: Path,
    out: Path,
    name: str,
    urdf: PreparedSource,
    srdf_info,
    srdf_path,
    spec: mujoco.MjSpec,
    model: mujoco.MjModel,
    joint_names: list[str],
    chosen: dict,
    motor_cfg: dict,
    motor_tables: dict,
    report,
    ee_site: str | None,
    control_rate: float,
    physics_timestep: float,
    log,
) -> None:
    """The fixed-base half of :func:`robots.importer.pipeline.import_robot` (its arguments).

    Raises:
        RobotImportError: see :func:`robots.importer.model.choose_ee_body`, or a result that does
            not load.
    """
    ee_body, ee_frame = choose_ee_body(model, urdf, ee_site, path)
    if ee_site is None:
        where = f"at site '{ee_frame}' of" if ee_frame else "on"
        log(
            f"note: end-effector site 'ee' {where} link '{ee_body}' (choose another with --ee-site)"
        )

    limits_out = capped_limits(urdf, chosen, motor_cfg, report, log)
    with staged(out, name, path) as (work, mjcf_path):
        finish_arm_mjcf(spec, ee_body, ee_frame, urdf, mjcf_path)
        write_pairs(mjcf_path, urdf, log)  # the MJCF's <contact><pair>s
        written_ranges(mjcf_path, joint_names, limits_out)
        motion = derive_motion_limits(spec, model, joint_names, limits_out, motor_cfg, chosen)
        home = motion.home
        pairs = collision_pairs(mjcf_path, model, urdf, srdf_info, home, path, log)
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
            disabled_by=disabled_by(urdf, srdf_path),
            lowered=report.lowered,
            motor_tables=motor_tables,
        )


def disabled_by(source: PreparedSource, srdf_path: Path | None) -> str | None:
    """What named the unchecked link pairs, for robot.toml's comment (None: nothing did)."""
    named = []
    if srdf_path is not None:
        named.append(f"the SRDF ({Path(srdf_path).name})")
    if source.disabled:
        named.append(f"the MJCF's <contact><exclude> ({source.path.name})")
    return " or ".join(named) or None


def finish_arm_mjcf(spec, ee_body: str, ee_frame: str | None, urdf, mjcf_path: Path) -> None:
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
