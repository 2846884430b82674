"""Model-side steps of the importer, shared by URDF and MJCF input: MJCF through
``mujoco.MjSpec``, limits, end effector, pairs, robot.toml.

They read a :class:`sim2real.robots.importer.source.PreparedSource` whatever the input format. Every constant
the importer chooses is named here with its reason; robot.toml repeats the reason beside each
value it writes.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from sim2real.robots.continuous import sampling_bounds
from sim2real.robots.importer.contact_pairs import rename_pair_geoms
from sim2real.robots.importer.physics_option import apply_options, source_options
from sim2real.robots.importer.source import (
    PreparedSource,
    RobotImportError,
    SrdfInfo,
    compile_built,
)
from sim2real.robots.packages import resolved_mjcf
from sim2real.robots.schema import MotorConfig

#: Soft-limit fraction written for every joint (as arm3/arm6).
SOFT_LIMIT_FRACTION = 0.9
#: Position error (rad) at which the plant's PD servo gives the full effort (kp = effort / this).
SERVO_FULL_EFFORT_ERROR = 0.05
#: Largest sqrt(kp / inertia) * timestep kept for the plant's PD servo (explicit stiffness).
SERVO_STABILITY = 0.3
#: Fraction of the torque left over gravity that the acceleration limit may use.
ACCELERATION_MARGIN = 0.5
#: Largest acceleration limit of an arm's joint, rad/s^2 (our choice: arm3/arm6's; an arm moves
#: its payload smoothly). A leg swings at gait frequency: ``LEGGED_MAX_ACCELERATION``.
MAX_ACCELERATION = 50.0
#: Largest acceleration limit of a leg's joint, rad/s^2: a 0.4 s trot swings a foot by ~0.5 rad
#: in 0.2 s, ~4 x 0.5 / 0.2^2 = 50 rad/s^2 on average with peaks several times that, which a
#: 50 rad/s^2 smoother flattens into shuffling; 1000 leaves the physical bound (0.5 x spare
#: torque / inertia) as the limit.
LEGGED_MAX_ACCELERATION = 1000.0
#: Jerk limit per unit of acceleration limit, 1/s (as arm3/arm6: 20 x acceleration per second).
JERK_PER_ACCELERATION = 20.0
#: Link pairs closer than this at the home pose (m) are not checked (they touch by design).
TOUCH_CLEARANCE = 0.001
#: Configurations sampled for inertia, gravity and the reachable workspace.
SAMPLES = 400
#: Margin (m) of the workspace box around the sampled reachable positions.
WORKSPACE_MARGIN = 0.05
#: The task's ``joint_fraction``: goals are end-effector positions of poses within this fraction
#: of each joint's half range about home (as arm3/arm6).
TASK_JOINT_FRACTION = 0.7
#: Smallest side of the task box, m (our choice: the task box of a planar arm has no extent
#: across its plane).
TASK_MIN_WIDTH = 0.01
#: Smallest fraction of the goal sampler's poses whose end effector lies in the 10th-90th
#: percentile box; below it the box spans every such pose (``GOAL_TRIES`` = 1000 draws of
#: ``sim2real.deploy.tasks.goals.sample_goal`` then miss with probability below 1e-20).
TASK_MIN_HITS = 0.05


@dataclass
class Motion:
    """Per-joint choices, arrays in joint order: home (rad), acceleration (rad/s^2), jerk
    (rad/s^3), kp (N m/rad), kd (N m s/rad), worst inertia (kg m^2) and gravity torque (N m);
    ``command_velocity`` (rad/s) the smoother's own velocity limit where it is not the soft
    velocity limit (a legged robot's PD targets), else None."""

    home: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    inertia: np.ndarray
    gravity: np.ndarray
    command_velocity: np.ndarray | None = None


def _sig(x: float, digits: int = 2) -> float:
    if x == 0 or not math.isfinite(x):
        return x
    return round(x, digits - 1 - int(math.floor(math.log10(abs(x)))))


def build_spec(
    urdf: PreparedSource,
    chosen: dict[str, str],
    motor_cfg: dict[str, MotorConfig],
    physics_timestep: float,
    options: list[str] | tuple[str, ...] = (),
) -> tuple[mujoco.MjSpec, mujoco.MjModel]:
    """MjSpec from the prepared URDF or MJCF: named geoms (``urdf.fitted_geoms`` gets the names
    of the boxes fitted to meshes), armature ``rotor_inertia * gear_ratio**2`` from each joint's
    motor, no actuator force range (``Robot.mjspec`` sets it), the physics timestep, and the
    integrator and solver settings of :func:`sim2real.robots.importer.physics_option.apply_options`
    (``options``: ``--option KEY=VALUE`` texts; ``urdf.physics`` says what was chosen).

    Raises:
        RobotImportError: MuJoCo's URDF (or MJCF) compiler refuses the description, or a bad
            ``--option``.
    """
    try:
        spec = mujoco.MjSpec.from_string(urdf.text)
        spec.compile()
    except ValueError as exc:
        message = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        raise RobotImportError(
            f"{urdf.path}: MuJoCo's {urdf.kind} compiler refuses it: {message}"
        ) from None
    spec.compiler.degree = False  # URDF: radians; MJCF: canonical text, radians already
    spec.option.timestep = physics_timestep
    urdf.physics = apply_options(spec, source_options(urdf.path), list(options))
    for joint in spec.joints:
        m = motor_cfg[chosen[joint.name]]
        joint.armature = m.rotor_inertia * m.gear_ratio**2
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
        joint.actfrcrange = [0.0, 0.0]
    renamed: dict[str, str] = {}
    for body in spec.bodies:
        geoms = list(body.geoms)
        for k, geom in enumerate(geoms):
            old = geom.name
            geom.name = body.name if len(geoms) == 1 else f"{body.name}_{k}"
            renamed[old] = geom.name
            if (body.name, k) in urdf.fitted:
                urdf.fitted_geoms.add(geom.name)
    rename_pair_geoms(urdf, renamed)  # the MJCF's <contact><pair>s follow their geoms
    model = compile_built(spec)
    return spec, model


def choose_ee_body(
    model: mujoco.MjModel, urdf: PreparedSource, ee: str | None, path: Path
) -> tuple[str, str | None]:
    """Where the end-effector site goes: ``(link, site or None)``.

    ``ee`` names a link, or (MJCF) one of the description's sites, whose frame the ``ee`` site
    takes. Without ``ee``: an MJCF site named ``ee`` (the toolkit's own convention), else a leaf
    frame link (fixed joint, such as ``tool0``) with the most movable joints above it, the
    shallowest of those (a tool frame rather than a finger tip); a moving leaf only when there is
    no fixed one.

    Raises:
        RobotImportError: ``ee`` is neither a link nor a site of the description.
    """
    if ee is not None and ee in urdf.renamed_sites:  # a site named like its body, renamed
        return urdf.sites[urdf.renamed_sites[ee]], urdf.renamed_sites[ee]
    if ee is not None:
        if ee in urdf.links:
            return ee, None
        if ee in urdf.sites:
            return urdf.sites[ee], ee
        sites = f", sites: {sorted(urdf.sites)}" if urdf.sites else ""
        raise RobotImportError(
            f"--ee-site {ee}: not a link{' or site' if sites else ''} of {path} "
            f"(links: {urdf.links}{sites})"
        )
    ee_site = urdf.renamed_sites.get("ee", "ee")
    if ee_site in urdf.sites:
        return urdf.sites[ee_site], ee_site
    children = {par for par, _, _ in urdf.parent.values()}
    best, best_key = urdf.root_link, (-1, -1, -(10**9))
    for link in urdf.links:
        if link in children:
            continue
        movable = depth = 0
        node = link
        while node in urdf.parent:
            par, _, kind = urdf.parent[node]
            movable += kind != "fixed"
            depth += 1
            node = par
        fixed_leaf = int(urdf.parent.get(link, ("", "", "fixed"))[2] == "fixed")
        key = (fixed_leaf, movable, -depth)
        if key > best_key:
            best, best_key = link, key
    return best, None


#: The ratio of a description's effort limit to its motor's peak torque above which the import
#: says the joint may sit behind a reduction of its own. Our choice: 1.5, above the spread of
#: the efforts descriptions round a motor's peak torque to (the Go2's hip and thigh 23.7 N m
#: against GO-M8010-6's 23.7), below the Go2 knee linkage's 1.917 (45.43 / 23.7, Unitree's
#: go2_description) that a ``--motor '*=go_m8010_6'`` alone capped to the motor's 23.7 N m.
FURTHER_REDUCTION_RATIO = 1.5


def further_reduction_hint(joint: str, ratio: float) -> str:
    """The import log's hint for a joint whose description's effort is ``ratio`` (>= 1) times
    its motor's peak torque: empty below :data:`FURTHER_REDUCTION_RATIO`."""
    if ratio < FURTHER_REDUCTION_RATIO:
        return ""
    return (
        f" (the description's is {ratio:.3g} x the motor's: a joint behind a further reduction, "
        f"a linkage or a belt, wants a motor file with that reduction, --motor {joint}=MODEL, "
        "as go_m8010_6_knee is for the Go2's knees)"
    )


def cap_limits(urdf: PreparedSource, chosen, motor_cfg, log) -> tuple[dict, list, list[str]]:
    """Velocity and effort limit of every movable joint: the lower of the description's value
    and the motor's capability (peak torque, no-load speed), whichever exists.

    Args:
        urdf: The prepared description. chosen: joint -> motor model. motor_cfg: model ->
            :class:`MotorConfig`. log: where each limit the motor lowers or sets is printed.

    Returns:
        ``(limits, lowered, notes)``: joint -> ``(lower rad, upper rad, velocity rad/s, effort
        N m)``; ``(joint, quantity, description value, motor value, unit)`` per limit the motor
        lowered; a note per limit the motor alone set.

    Raises:
        RobotImportError: neither the description nor the motor gives a velocity limit.
    """
    limits, lowered, notes = {}, [], []
    for j in urdf.movable:
        m = motor_cfg[chosen[j]]
        src = urdf.joints[j]
        effort = min(v for v in (src.effort, m.peak_torque) if v is not None and v > 0)
        velocity = min(v for v in (src.velocity, m.max_velocity, np.inf) if v is not None and v > 0)
        if not np.isfinite(velocity):
            element = (
                f"<joint name='{j}'><limit velocity>: missing or zero"
                if urdf.kind == "URDF"
                else f"<joint name='{j}'>: the MJCF has no velocity limit"
            )
            raise RobotImportError(
                f"{urdf.path}: {element}, and motor '{chosen[j]}' gives no max_velocity; "
                f"expected a velocity limit in rad/s (--velocity {j}=RAD_S)"
            )
        if src.effort is not None and src.effort > effort:
            lowered.append((j, "effort", src.effort, effort, "N m"))
            log(
                f"joint {j}: effort limit {src.effort:g} N m ({src.effort_from}) -> "
                f"{effort:g} N m: {chosen[j]} peak torque at the output"
                + further_reduction_hint(j, src.effort / effort)
            )
        if src.velocity is not None and src.velocity > velocity:
            lowered.append((j, "velocity", src.velocity, velocity, "rad/s"))
            log(
                f"joint {j}: velocity limit {src.velocity:g} rad/s ({src.velocity_from}) -> "
                f"{velocity:g} rad/s: {chosen[j]} no-load speed at the output"
            )
        for value, quantity, unit, what in (
            (src.effort, "effort", "N m", "peak torque"),
            (src.velocity, "velocity", "rad/s", "no-load speed"),
        ):
            if value is None or value <= 0:
                motor_value = effort if quantity == "effort" else velocity
                notes.append(
                    f"joint {j}: {quantity} limit {motor_value:g} {unit}: {chosen[j]} {what} at "
                    f"the output (the {urdf.kind} gives none)"
                )
                log(f"note: {notes[-1]}")
        limits[j] = (src.lower, src.upper, velocity, effort)
    return limits, lowered, notes


def derive_motion_limits(
    spec, model, joint_names, limits, motor_cfg, chosen, max_acceleration=MAX_ACCELERATION
) -> Motion:
    """Home pose, acceleration and jerk limits and plant servo gains (see the constants).

    The acceleration limit is ``ACCELERATION_MARGIN`` x (effort - worst gravity torque) / worst
    joint-space inertia (armature included) over ``SAMPLES`` seeded configurations; kp gives the
    full effort at ``SERVO_FULL_EFFORT_ERROR`` rad (lowered for explicit stability at the physics
    timestep), kd = 2 sqrt(kp x worst inertia) (critical damping). The acceleration limit is
    clipped into [0.5, ``max_acceleration``] rad/s^2.
    """
    n = len(joint_names)
    lo = np.array([limits[j][0] for j in joint_names])
    hi = np.array([limits[j][1] for j in joint_names])
    effort = np.array([limits[j][3] for j in joint_names])
    lo, hi = sampling_bounds(lo, hi)  # a continuous joint: one turn
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    soft_lo, soft_hi = centre - SOFT_LIMIT_FRACTION * half, centre + SOFT_LIMIT_FRACTION * half
    home = np.clip(np.zeros(n), soft_lo, soft_hi)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    inertia_max = np.zeros(n)
    inertia_min = np.full(n, np.inf)
    gravity = np.zeros(n)
    full = np.zeros((model.nv, model.nv))
    for _ in range(SAMPLES):
        data.qpos[:] = rng.uniform(lo, hi)
        data.qvel[:] = 0.0
        mujoco.mj_forward(model, data)
        mujoco.mj_fullM(model, data, full)
        diag = np.diag(full)
        inertia_max = np.maximum(inertia_max, diag)
        inertia_min = np.minimum(inertia_min, diag)
        gravity = np.maximum(gravity, np.abs(data.qfrc_bias))
    spare = np.maximum(effort - gravity, 0.25 * effort)
    acc = np.array(
        [_sig(a) for a in np.clip(ACCELERATION_MARGIN * spare / inertia_max, 0.5, max_acceleration)]
    )
    jerk = JERK_PER_ACCELERATION * acc
    dt = model.opt.timestep
    kp = np.minimum(effort / SERVO_FULL_EFFORT_ERROR, (SERVO_STABILITY / dt) ** 2 * inertia_min)
    kp = np.array([_sig(k) for k in kp])
    kd = np.array([_sig(2.0 * math.sqrt(k * m)) for k, m in zip(kp, inertia_max, strict=True)])
    return Motion(home, acc, jerk, kp, kd, inertia_max, gravity)


def _groups(urdf: PreparedSource) -> dict[str, str]:
    """Link -> the link its rigid group hangs from (fixed joints merge links into one group)."""
    out = {}
    for link in urdf.links:
        node = link
        while node in urdf.parent and urdf.parent[node][2] == "fixed":
            node = urdf.parent[node][0]
        out[link] = node
    return out


def choose_collision_pairs(
    mjcf_path: Path,
    model: mujoco.MjModel,
    urdf: PreparedSource,
    srdf: SrdfInfo | None,
    home: np.ndarray,
    path: Path,
    clearance: float = TOUCH_CLEARANCE,
):
    """Self-collision pairs for the guard (geom names) and the MuJoCo contact exclusions.

    Candidates: the geoms that can touch (``contype`` or ``conaffinity`` set: visual-only geoms
    never do) of links of different rigid groups that are not parent and child, minus the SRDF's
    ``disable_collisions`` pairs when there is an SRDF; pairs closer than ``clearance`` (m) at
    the home pose are dropped (they touch by design or through a coarse collision shape). The
    plant (MuJoCo) checks contact only between the pairs the guard checks.

    Returns:
        (geom pairs, excluded body pairs, dropped (link, link, distance) triples).
    """
    import pinocchio as pin

    resolved = resolved_mjcf(mjcf_path)
    try:
        pin_model = pin.buildModelFromMJCF(str(resolved))
        geom = pin.buildGeomFromMJCF(pin_model, str(resolved), pin.VISUAL)
    except Exception as exc:  # noqa: BLE001 - Pinocchio's parser raises anything (IndexError, ...)
        raise RobotImportError(
            f"{mjcf_path}: Pinocchio's MJCF parser refuses the reduced robot file: "
            f"{type(exc).__name__}: "
            + "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        ) from None
    index = {g.name: i for i, g in enumerate(geom.geometryObjects)}
    body_geoms: dict[str, list[str]] = {}
    for g in range(model.ngeom):
        if model.geom_contype[g] or model.geom_conaffinity[g]:  # visual-only geoms never touch
            body = model.body(model.geom_bodyid[g]).name
            body_geoms.setdefault(body, []).append(model.geom(g).name)
    group = _groups(urdf)
    adjacent = {
        tuple(sorted((group[child], group[par])))
        for child, (par, _, kind) in urdf.parent.items()
        if kind != "fixed"
    }
    data = pin_model.createData()
    gdata = pin.GeometryData(geom)
    q = np.asarray(home, dtype=np.float64)
    if pin_model.nq == q.size + 7:  # a free-flyer root (floating base): the base at the origin
        q = np.concatenate([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], q])
    pin.updateGeometryPlacements(pin_model, data, geom, gdata, q)
    pairs, kept, dropped = [], set(), []
    for a, b in itertools.combinations([x for x in urdf.links if x in body_geoms], 2):
        key = tuple(sorted((a, b)))
        if group[a] == group[b] or tuple(sorted((group[a], group[b]))) in adjacent:
            continue
        if srdf is not None and key in srdf.disabled:
            continue
        geom_pairs = [(ga, gb) for ga in body_geoms[a] for gb in body_geoms[b]]
        dist = np.inf
        for ga, gb in geom_pairs:
            dist = min(dist, _distance(geom, gdata, index[ga], index[gb]))
        if dist < clearance:
            dropped.append((a, b, max(dist, 0.0)))
            continue
        pairs.extend(geom_pairs)
        kept.add(key)
    bodies = [x for x in urdf.links if x in body_geoms]
    excluded = [
        (a, b) for a, b in itertools.combinations(bodies, 2) if tuple(sorted((a, b))) not in kept
    ]
    return pairs, excluded, dropped


def _distance(geom, gdata, i: int, j: int) -> float:
    import coal

    req, res = coal.DistanceRequest(), coal.DistanceResult()
    oi, oj = geom.geometryObjects[i], geom.geometryObjects[j]
    coal.distance(oi.geometry, gdata.oMg[i], oj.geometry, gdata.oMg[j], req, res)
    return float(res.min_distance)


def sample_workspace(mjcf_path: Path, joint_names, limits, home) -> dict:
    """Workspace box, task box and success radius from ``SAMPLES`` reachable positions (m).

    Workspace: the box of every sampled end-effector position within the hard limits, plus
    ``WORKSPACE_MARGIN``, cut at 5 cm below the base (the table) unless home is lower. Task: the
    10th-90th percentile box of the positions the goal sampler draws (poses within
    ``TASK_JOINT_FRACTION`` of each joint's half range about home, in the soft limits), above the
    table, each side at least ``TASK_MIN_WIDTH``, rounded outward to 0.1 mm; the box of all of
    them when fewer than ``TASK_MIN_HITS`` fall inside. Success radius 6 % of the largest reach
    (at least 1 cm).
    """
    model = mujoco.MjModel.from_xml_path(str(resolved_mjcf(mjcf_path)))
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "ee")
    lo = np.array([limits[j][0] for j in joint_names])
    hi = np.array([limits[j][1] for j in joint_names])
    lo, hi = sampling_bounds(lo, hi)
    rng = np.random.default_rng(1)

    def ee(q):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        return data.site_xpos[site].copy()

    full = np.array([ee(rng.uniform(lo, hi)) for _ in range(4 * SAMPLES)])
    home_ee = ee(home)
    span = TASK_JOINT_FRACTION * (hi - lo) / 2
    # the goal sampler's draw (sim2real.deploy.tasks.goals.sample_goal): about home, in the soft limits
    centre, half = (lo + hi) / 2, SOFT_LIMIT_FRACTION * (hi - lo) / 2
    inner = np.array(
        [
            ee(np.clip(home + rng.uniform(-span, span), centre - half, centre + half))
            for _ in range(4 * SAMPLES)
        ]
    )
    ws_min = full.min(axis=0) - WORKSPACE_MARGIN
    ws_max = full.max(axis=0) + WORKSPACE_MARGIN
    ws_min[2] = max(ws_min[2], min(-0.05, home_ee[2] - WORKSPACE_MARGIN))
    above = inner[inner[:, 2] > ws_min[2] + WORKSPACE_MARGIN]
    above = above if len(above) > 20 else inner
    task_min, task_max = _task_box(above, 10)
    if np.mean(np.all((inner >= task_min) & (inner <= task_max), axis=1)) < TASK_MIN_HITS:
        task_min, task_max = _task_box(inner, 0)
    reach = float(np.max(np.linalg.norm(full, axis=1)))
    return {
        "workspace_min": ws_min,
        "workspace_max": ws_max,
        "task_min": task_min,
        "task_max": task_max,
        "success_radius": max(0.01, _sig(0.06 * reach)),
        "home_ee": home_ee,
    }


def _task_box(points: np.ndarray, percent: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``percent``-th to ``100 - percent``-th percentile box of ``points`` (m), each side at
    least ``TASK_MIN_WIDTH`` about its middle (a planar arm's end effector keeps one coordinate),
    rounded outward to the 0.1 mm robot.toml writes."""
    a = np.percentile(points, percent, axis=0)
    b = np.percentile(points, 100 - percent, axis=0)
    middle, half = (a + b) / 2, np.maximum((b - a) / 2, TASK_MIN_WIDTH / 2)
    return np.floor((middle - half) * 1e4) / 1e4, np.ceil((middle + half) * 1e4) / 1e4
