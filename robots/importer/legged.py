"""Floating-base (legged) robots for the importer: ``robot-import ... --floating-base``.

After the steps every import shares (:func:`robots.importer.model.build_spec`, motor limits), a
floating-base robot gets, in its MJCF (:func:`finish_floating_mjcf`):

- a MuJoCo free joint ``root`` on the root link (Pinocchio's MJCF parser reads it as its
  free-flyer root joint, ``pin.JointModelFreeFlyer``), the base placed so that the feet touch
  the floor at the home pose;
- a flat floor (a plane ``floor`` in the world body) and a light;
- a site ``imu`` at the IMU link (a link named ``imu``, or ``--imu LINK``) with MuJoCo ``gyro``
  and ``accelerometer`` sensors;
- per foot (leaf links at the end of the longest chains of movable joints, or ``--foot LINK``):
  the foot link's collision box replaced by a sphere of the box's mean half-size (a point-like
  foot, as legged simulators model one), a site ``<foot>`` at its centre and a MuJoCo ``touch``
  sensor on it (the normal force of the contacts inside the site: foot contact). Sphere and site
  go on the nearest body a joint moves (the calf): Pinocchio's MJCF parser misplaces sites of
  joint-less child bodies, and a touch sensor counts the contacts of its own body.

robot.toml (:func:`write_legged_toml`) then has a ``[base]`` table, ``[sensors.imu]`` and
``[sensors.contact]`` with the defaults below (each with its source), no workspace box and no
task region (velocity commands are a later issue).
"""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import mujoco
import numpy as np

from robots.importer.model import Motion, _f, _sig, _vec, joint_lines, limit_notes, sensor_lines
from robots.importer.urdf import PreparedSource, RobotImportError

#: Name of the MuJoCo free joint of the base (Pinocchio names its free-flyer joint the same).
FREE_JOINT = "root"
#: Site of the IMU (its gyro and accelerometer sensors are ``imu_gyro``, ``imu_accelerometer``).
IMU_SITE = "imu"
#: Link pairs closer than this at the home pose (m) are not checked and never collide in the
#: plant: the importer's bounding boxes of neighbouring legs' links (the rear hips of go2 are
#: 1-2 mm apart and touch as soon as the legs carry the body) overlap where the meshes do not.
LEG_CLEARANCE = 0.01
#: The foot site (and its touch sensor's) margin over the foot sphere, m: the contact point of
#: a sphere on a plane lies inside the sphere by half the penetration (a few mm at most).
TOUCH_MARGIN = 0.005

#: Normalizers of the seed's IMU noise figures (section 5 gives sigma on normalized readings):
#: angular rate over 4 rad/s (legged_gym's ``obs_scales.ang_vel = 0.25``, i.e. 1 / 4 rad/s),
#: acceleration over standard gravity.
ANGULAR_RATE_SCALE = 4.0  # rad/s
ACCELERATION_SCALE = 9.80665  # m/s^2
#: Default IMU white noise: the middle of seed section 5's ranges (angular rate 0.01-0.03,
#: linear acceleration 0.03-0.08, normalized).
GYRO_NOISE_SIGMA = 0.02 * ANGULAR_RATE_SCALE  # 0.08 rad/s
ACCEL_NOISE_SIGMA = 0.055 * ACCELERATION_SCALE  # 0.54 m/s^2
#: Turn-on bias, 1 sigma: a calibrated MEMS IMU of the Bosch BMI088 class (datasheet
#: BST-BMI088-DS001: zero-rate offset +-1 deg/s, zero-g offset +-20 mg typical); we take
#: 0.01 rad/s and 0.05 m/s^2 (about 5 mg, after the user's level calibration).
GYRO_BIAS_SIGMA = 0.01  # rad/s
ACCEL_BIAS_SIGMA = 0.05  # m/s^2
#: Bias random walk: Kalibr's ADIS16448 example (gyroscope_random_walk 3.9e-5 rad/s^2/sqrt(Hz),
#: accelerometer_random_walk 4.3e-4 m/s^3/sqrt(Hz)) inflated 10x for a robot's vibration and
#: temperature, as Kalibr's "IMU Noise Model" page advises for real conditions.
GYRO_BIAS_WALK = 4e-4  # rad/s/sqrt(s)
ACCEL_BIAS_WALK = 4e-3  # m/s^2/sqrt(s)
#: Foot force noise: seed section 5 (force sensors 0.05-0.10 normalized), the lower end, over
#: the standing load of one foot (m g / n_feet). Contact threshold: 3 sigma above it, and at
#: least 5 N.
FORCE_NOISE_FRACTION = 0.05
CONTACT_THRESHOLD_SIGMAS = 3.0
#: The soak's pushes on the base (``[soak] push_force``): the largest gives the robot legged_gym's
#: largest push, a base velocity change of ``PUSH_VELOCITY`` (unitree_rl_gym
#: LeggedRobotCfg.domain_rand.max_push_vel_xy), over the longest push, ``PUSH_TIME`` (eval.
#: fault_schedule.FaultRanges.push_duration); the smallest ``PUSH_LOW`` of it (our choice).
PUSH_VELOCITY = 1.0  # m/s
PUSH_TIME = 0.5  # s
PUSH_LOW = 0.2


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


def choose_imu(prepared: PreparedSource, flag: str | None, log) -> str:
    """The IMU link: ``--imu LINK``, else a link named ``imu``, else the root link.

    Raises:
        RobotImportError: ``--imu`` names no link.
    """
    if flag is not None:
        if flag not in prepared.links:
            raise RobotImportError(f"--imu {flag}: not a link of {prepared.path.name}")
        return flag
    if "imu" in prepared.links:
        return "imu"
    log(f"note: no link named 'imu': the IMU site is at the root link {prepared.root_link}")
    return prepared.root_link


def _moving_ancestor(model: mujoco.MjModel, body: int) -> int:
    while body > 0 and model.body_jntnum[body] == 0 and model.body_parentid[body] > 0:
        body = model.body_parentid[body]
    return body


def _relative(data: mujoco.MjData, anc: int, pos: np.ndarray) -> np.ndarray:
    return data.xmat[anc].reshape(3, 3).T @ (pos - data.xpos[anc])


def _box_to_capsule(geom) -> None:
    """Replace a leg link's collision box by the capsule along its long axis (radius: the mean
    of the two other half-sizes; legged_gym turns its legs' cylinders into capsules too): the
    corners of a calf's box reach below the foot sphere once the calf leans (go2's front calves
    touched the floor standing), a thigh's below the knee."""
    size = np.asarray(geom.size, dtype=np.float64)
    axis = int(np.argmax(size))
    radius = float(np.mean(np.delete(size, axis)))
    half = max(float(size[axis]) - radius, 1e-4)
    # the capsule's axis is its local z: turn the box's long axis onto it
    to_z = {0: [0.5**0.5, 0.0, 0.5**0.5, 0.0], 1: [0.5**0.5, -(0.5**0.5), 0.0, 0.0]}
    quat = np.asarray(geom.quat, dtype=np.float64)
    if axis in to_z:
        out = np.zeros(4)
        mujoco.mju_mulQuat(out, quat, np.array(to_z[axis]))
        quat = out
    geom.type = mujoco.mjtGeom.mjGEOM_CAPSULE
    geom.quat = quat
    geom.size = [radius, half, 0.0]


def finish_floating_mjcf(
    spec: mujoco.MjSpec,
    prepared: PreparedSource,
    feet: list[str],
    imu_link: str,
    joint_names: list[str],
    home: np.ndarray,
    mjcf_path: Path,
) -> dict:
    """Add the free joint, floor, IMU and foot sites, foot spheres and sensors (module
    docstring) to ``spec`` and write the MJCF to ``mjcf_path``.

    Returns:
        ``{"feet": foot site names, "foot_radius": m, "standing_height": m}``.

    Raises:
        RobotImportError: a foot link without a collision geometry.
    """
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)  # base at the origin, joints at 0
    radius = {}
    for foot in feet:
        body = spec.body(foot)
        geoms = list(body.geoms)
        b = model.body(foot).id
        if not geoms:
            raise RobotImportError(
                f"{prepared.path}: <link name='{foot}'> (a foot): no collision geometry; "
                "expected one (its size gives the foot sphere)"
            )
        corners = []
        for geom in geoms:
            g = model.geom(geom.name).id
            rot = data.geom_xmat[g].reshape(3, 3)
            for sign in np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T:
                corners.append(data.geom_xpos[g] + rot @ (sign * model.geom_size[g]))
            spec.delete(geom)
        corners = np.array(corners)
        centre = (corners.min(axis=0) + corners.max(axis=0)) / 2
        r = float(np.mean(corners.max(axis=0) - corners.min(axis=0)) / 2)
        radius[foot] = r = _sig(r, 3)
        anc = _moving_ancestor(model, b)
        pos = _relative(data, anc, centre)
        host = spec.body(model.body(anc).name)
        host.add_geom(name=foot, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[r, 0, 0], pos=pos)
        host.add_site(name=foot, size=[r + TOUCH_MARGIN, 0, 0], pos=pos)
        spec.add_sensor(
            name=f"{foot}_touch",
            type=mujoco.mjtSensor.mjSENS_TOUCH,
            objtype=mujoco.mjtObj.mjOBJ_SITE,
            objname=foot,
        )
    for body in spec.bodies:  # leg links (bodies a hinge moves): capsules, as legged_gym's
        if any(j.type == mujoco.mjtJoint.mjJNT_HINGE for j in body.joints):
            for geom in list(body.geoms):
                if geom.type == mujoco.mjtGeom.mjGEOM_BOX:
                    _box_to_capsule(geom)
    b = model.body(imu_link).id
    anc = _moving_ancestor(model, b)
    imu_quat, inv = np.zeros(4), np.zeros(4)
    mujoco.mju_negQuat(inv, data.xquat[anc])
    mujoco.mju_mulQuat(imu_quat, inv, data.xquat[b])
    spec.body(model.body(anc).name).add_site(
        name=IMU_SITE,
        size=[0.01, 0.01, 0.01],
        pos=_relative(data, anc, data.xpos[b]),
        quat=imu_quat,
    )
    for kind, name in (
        (mujoco.mjtSensor.mjSENS_GYRO, "imu_gyro"),
        (mujoco.mjtSensor.mjSENS_ACCELEROMETER, "imu_accelerometer"),
    ):
        spec.add_sensor(name=name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=IMU_SITE)

    # standing height: the lowest foot sphere touches the floor at the home pose
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[:] = home
    mujoco.mj_kinematics(model, data)
    bottom = min(data.site_xpos[model.site(f).id][2] - radius[f] for f in feet)
    height = _sig(-bottom, 4)
    root = spec.body(prepared.root_link)
    root.pos = [0.0, 0.0, height]
    root.add_freejoint(name=FREE_JOINT)
    spec.worldbody.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 0.05], rgba=[0.5] * 3 + [1]
    )
    spec.worldbody.add_light(
        name="sun", pos=[0, 0, 3], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    )
    spec.compile()
    xml = spec.to_xml()
    if prepared.meshdir_abs is not None:
        xml = xml.replace(
            f'meshdir="{prepared.meshdir_abs}"', f'meshdir="{prepared.meshdir_uri}"', 1
        )
    header = (
        f"<!-- Generated by robot-import (floating base) from {prepared.display} with MuJoCo's "
        f"{prepared.kind} compiler (mujoco.MjSpec). Radians, explicit inertials, no actuators "
        "(Robot.mjspec adds them per control mode). A free joint 'root' on the base, a flat "
        "floor, an IMU site with gyro and accelerometer, foot spheres with touch sensors. -->\n"
    )
    mjcf_path.write_text(header + xml, encoding="utf-8")
    return {"feet": list(feet), "foot_radius": radius, "standing_height": height}


def robot_mass(mjcf_path: Path) -> float:
    """Total mass (kg) of the robot in ``mjcf_path`` (MuJoCo, resolved meshdir)."""
    from robots.loading import _resolved_mjcf

    model = mujoco.MjModel.from_xml_path(str(_resolved_mjcf(mjcf_path)))
    return float(model.body_subtreemass[0])


def write_legged_toml(
    path: Path,
    *,
    name: str,
    prepared: PreparedSource,
    mjcf: str,
    joint_names: list[str],
    limits: dict,
    motion: Motion,
    gains_from: dict[str, str],
    chosen: dict[str, str],
    motor_cfg: dict,
    pairs: list,
    legged: dict,
    imu_link: str,
    mass: float,
    control_rate: float,
    physics_timestep: float,
    home_from: str,
    disabled_by: str | None,
    lowered: list,
    notes: list[str],
    command: list[str],
    tables: list[str] = (),
) -> None:
    """robot.toml of a floating-base robot, a comment giving the reason of every value.

    ``gains_from``: joint -> where its kp and kd came from ('--kp/--kd' or the importer's
    rule); ``notes``: ``--note`` lines for the header (sources of flag values); ``command``:
    the command line that regenerates the folder; ``tables``: lines of more tables, at the end
    (``[unitree]``: :mod:`robots.importer.unitree`).
    """
    kind = prepared.kind
    resolution = min(motor_cfg[m].encoder_resolution or 16384 for m in set(chosen.values()))
    quantum = 2 * math.pi / resolution
    low = {(j, q): (a, b) for j, q, a, b, _ in lowered}
    feet = legged["feet"]
    load = mass * ACCELERATION_SCALE / len(feet)
    push = mass * PUSH_VELOCITY / PUSH_TIME  # N, the soak's largest push
    force_sigma = _sig(FORCE_NOISE_FRACTION * load, 2)
    threshold = _sig(max(5.0, CONTACT_THRESHOLD_SIGMAS * force_sigma), 2)
    lines = [
        f"# {name}: imported by robot-import --floating-base from {prepared.display}.",
        "# Regenerate with (from the repository root):",
        "#   " + " ".join(shlex.quote(a) for a in command),
        f"# Joint order and position limits from the {kind}; velocity and effort limits are the "
        "lower",
        f"# of the {kind}'s and the motor's (robots/motors/<model>.toml); SI units, radians.",
        *[f"# {line}" for note in notes for line in note.splitlines()],
        f'name = "{name}"',
        f'mjcf = "{mjcf}"',
        "",
        "[control]",
        'mode = "position"            # joint position targets, PD at the physics rate',
        f"control_rate = {_f(control_rate)}          # Hz (robot-import --control-rate)",
        f"physics_timestep = {_f(physics_timestep)}     # s (robot-import --physics-timestep)",
        f"# rad: {home_from}",
        f"home = {_vec(motion.home)}",
        "",
        "# acceleration_limit: 0.5 x (effort - worst gravity torque) / worst joint inertia with",
        "# armature (rotor inertia x ratio^2), base held, 400 seeded poses; jerk_limit: 20 x",
        "# acceleration. kp, kd: see the comment of each joint.",
    ]
    for i, j in enumerate(joint_names):
        lo, hi, vel, eff = limits[j]
        src = prepared.joints[j]
        vnote, enote = limit_notes(j, src, low)
        lines += joint_lines(
            j, i, (lo, hi, vel, eff), kind, (vnote, enote), motion, chosen[j], gains_from[j]
        )
    lines += [
        "",
        *sensor_lines(chosen, resolution, quantum, control_rate, "degC"),
        "",
        "# IMU at site 'imu' (link " + imu_link + "): Kalibr's noise model (robots/schema.py).",
        "[sensors.imu]",
        "# seed section 5: angular rate sigma 0.01-0.03 over 4 rad/s (legged_gym ang_vel scale",
        "# 0.25), linear acceleration 0.03-0.08 over g; the middle of each range",
        f"gyro_noise_sigma = {_f(_sig(GYRO_NOISE_SIGMA, 3))}  # rad/s",
        f"accel_noise_sigma = {_f(_sig(ACCEL_NOISE_SIGMA, 3))}  # m/s^2",
        "# turn-on bias: BMI088-class MEMS (datasheet BST-BMI088-DS001: +-1 deg/s, +-20 mg",
        "# typical), after a level calibration",
        f"gyro_bias_sigma = {_f(GYRO_BIAS_SIGMA)}  # rad/s",
        f"accel_bias_sigma = {_f(ACCEL_BIAS_SIGMA)}  # m/s^2",
        "# bias random walk: Kalibr's ADIS16448 example x 10 (Kalibr wiki, 'IMU Noise Model')",
        f"gyro_bias_walk = {_f(GYRO_BIAS_WALK)}  # rad/s/sqrt(s)",
        f"accel_bias_walk = {_f(ACCEL_BIAS_WALK)}  # m/s^2/sqrt(s)",
        f"rate = {_f(control_rate)}  # Hz, one reading a control tick",
        "latency_ticks = 0",
        "dropout = 0.0",
        "",
        "# Foot contact: the touch sensor's normal force (N) + noise, thresholded.",
        "[sensors.contact]",
        f"# noise: seed section 5 (force 0.05-0.10 normalized) x the standing load of a foot, "
        f"{load:.1f} N",
        f"force_noise_sigma = {_f(force_sigma)}  # N",
        f"threshold = {_f(threshold)}  # N, {CONTACT_THRESHOLD_SIGMAS:g} noise sigmas, >= 5 N",
        f"rate = {_f(control_rate)}  # Hz",
        "latency_ticks = 0",
        "",
        "[safety]",
        "# No end effector and no workspace box: a legged robot walks anywhere.",
        (
            f"# Geom pairs of links {disabled_by} does not disable, "
            if disabled_by
            else "# Geom pairs of non-adjacent links, "
        )
        + "apart at home; the plant checks contact only between these (and the floor).",
        "collision_pairs = [",
        *[f'  ["{a}", "{b}"],' for a, b in pairs],
        "]",
        "stale_limit = 0.05",
        "",
        "[base]",
        f'body = "{prepared.root_link}"  # carries the free joint "{FREE_JOINT}"',
        f'imu_site = "{IMU_SITE}"',
        "# foot sites, spheres of radius "
        + ", ".join(f"{legged['foot_radius'][f]:g}" for f in feet)
        + " m (the foot collision box's mean half-size)",
        "feet = [" + ", ".join(f'"{f}"' for f in feet) + "]",
        f"standing_height = {_f(legged['standing_height'])}  # m, base above the floor at home",
        "",
        "[soak]",
        "# Pushes on the base: up to the impulse of legged_gym's largest push (a "
        f"{PUSH_VELOCITY:g} m/s base velocity",
        "# change, unitree_rl_gym LeggedRobotCfg.domain_rand.max_push_vel_xy) delivered over the "
        "longest",
        f"# push ({PUSH_TIME:g} s): {mass:.1f} kg x {PUSH_VELOCITY:g} m/s / {PUSH_TIME:g} s; the "
        f"low end {PUSH_LOW:g} of it.",
        f"push_force = [{_f(_sig(PUSH_LOW * push))}, {_f(_sig(push))}]  # N",
        *tables,
        "",
    ]
    path.write_text("\n".join(lines), encoding="utf-8")


def _per_joint(flags: list[str], joint_names: list[str], flag: str) -> dict[str, float]:
    """``JOINT=VALUE`` flags (shell patterns; later flags win) -> joint -> value."""
    import fnmatch

    out: dict[str, float] = {}
    for text in flags:
        pattern, sep, value = text.partition("=")
        try:
            number = float(value)
            if not sep or not pattern or not math.isfinite(number):
                raise ValueError
        except ValueError:
            raise RobotImportError(
                f"{flag} '{text}': expected JOINT=VALUE with a finite number (JOINT may be a "
                "shell pattern, e.g. '*_calf_joint=-1.5')"
            ) from None
        hits = [j for j in joint_names if fnmatch.fnmatchcase(j, pattern)]
        if not hits:
            raise RobotImportError(
                f"{flag} '{text}': pattern '{pattern}' matches no joint (joints: {joint_names})"
            )
        for j in hits:
            out[j] = number
    return out


def import_floating_base(
    *,
    path,
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
    report,
    feet: list[str],
    imu: str | None,
    kp: list[str],
    kd: list[str],
    home: list[str],
    notes: list[str],
    control_rate: float,
    physics_timestep: float,
    command: list[str],
    log,
    unitree: dict | None = None,
) -> None:
    """The floating-base half of :func:`robots.importer.cli.import_robot` (its arguments).

    Raises:
        RobotImportError: see :func:`choose_feet`, :func:`choose_imu`,
            :func:`finish_floating_mjcf`, a bad ``--kp``/``--kd``/``--home`` flag or a home
            pose outside the limits, or a result that does not load.
    """
    import shutil
    import tempfile

    from robots.importer.cli import _add_contact_excludes, _disabled_by
    from robots.importer.model import (
        LEGGED_MAX_ACCELERATION,
        cap_limits,
        choose_collision_pairs,
        derive_motion_limits,
    )
    from robots.loading import _resolved_mjcf, load_robot
    from robots.robot import RobotSpecError

    foot_links = choose_feet(urdf, feet)
    imu_link = choose_imu(urdf, imu, log)
    tables = []
    if unitree is not None:
        from robots.importer.unitree import unitree_lines

        tables = unitree_lines(joint_names=joint_names, feet=foot_links, **unitree)
    log(f"note: feet {foot_links}, IMU at link {imu_link}")
    limits_out, lowered, lnotes = cap_limits(urdf, chosen, motor_cfg, log)
    report.lowered += lowered
    report.notes += lnotes
    home_set = _per_joint(home, joint_names, "--home")
    kp_set = _per_joint(kp, joint_names, "--kp")
    kd_set = _per_joint(kd, joint_names, "--kd")
    for flag, values in (("--kp", kp_set), ("--kd", kd_set)):
        bad = {j: v for j, v in values.items() if v < 0 or (flag == "--kp" and v == 0)}
        if bad:
            raise RobotImportError(f"{flag}: gains must be positive (kd may be 0), got {bad}")

    def motion_now():
        motion = derive_motion_limits(
            spec, model, joint_names, limits_out, motor_cfg, chosen, LEGGED_MAX_ACCELERATION
        )
        for i, j in enumerate(joint_names):
            motion.home[i] = home_set.get(j, motion.home[i])
            motion.kp[i] = kp_set.get(j, motion.kp[i])
            motion.kd[i] = kd_set.get(j, motion.kd[i])
            lo, hi = limits_out[j][:2]
            if not lo <= motion.home[i] <= hi:
                raise RobotImportError(
                    f"--home: joint {j} at {motion.home[i]} rad is outside its limits [{lo}, {hi}]"
                )
        return motion

    motion = motion_now()
    gains_from = {
        j: "--kp/--kd" if j in kp_set or j in kd_set else "the importer's rule (see above)"
        for j in joint_names
    }
    home_from = (
        "--home flags (see the notes above)" if home_set else "0 clipped into the soft limits"
    )
    with tempfile.TemporaryDirectory(prefix=f".{name}-", dir=out.parent) as tmp:
        work = Path(tmp) / name
        work.mkdir()
        mjcf_path = work / f"{name}.xml"
        legged = finish_floating_mjcf(
            spec, urdf, foot_links, imu_link, joint_names, motion.home, mjcf_path
        )
        written = mujoco.MjModel.from_xml_path(str(_resolved_mjcf(mjcf_path)))
        for i, j in enumerate(joint_names):  # the MJCF writes 6 significant digits
            lo, hi = (float(x) for x in written.jnt_range[i + 1])
            limits_out[j] = (lo, hi, *limits_out[j][2:])
        motion = motion_now()
        pairs, excluded, dropped = choose_collision_pairs(
            mjcf_path, written, urdf, srdf_info, motion.home, path, LEG_CLEARANCE
        )
        for a, b, d in dropped:
            log(f"note: links {a} and {b} are {d * 1000:.1f} mm apart at home: pair not checked")
        if excluded:
            _add_contact_excludes(mjcf_path, excluded)
        write_legged_toml(
            work / "robot.toml",
            name=name,
            prepared=urdf,
            mjcf=mjcf_path.name,
            joint_names=joint_names,
            limits=limits_out,
            motion=motion,
            gains_from=gains_from,
            chosen=chosen,
            motor_cfg=motor_cfg,
            pairs=pairs,
            legged=legged,
            imu_link=imu_link,
            mass=robot_mass(mjcf_path),
            control_rate=control_rate,
            physics_timestep=physics_timestep,
            home_from=home_from,
            disabled_by=_disabled_by(urdf, srdf_path),
            lowered=report.lowered,
            notes=notes,
            command=command,
            tables=tables,
        )
        try:
            load_robot(work)
        except RobotSpecError as exc:
            raise RobotImportError(f"{path}: the imported robot does not load: {exc}") from None
        if out.exists():
            shutil.rmtree(out)
        work.rename(out)
