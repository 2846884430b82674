"""HIMLoco's Go2 (or another rl_sar quadruped's policy, ``--policy``) on terrain tiles in a bare
MuJoCo loop that follows rl_sar's runtime: the own loop of ``deploy-run --terrain`` and of
``bench.push_reference --rl-sar``.

rl_sar (fan-ziqi/rl_sar e384912) runs a policy folder, by default ``policy/go2/himloco``
(``himloco.pt``), on unitree_mujoco's MJCF of its robot (``go2.xml``; :mod:`.rl_sar_robot`:
which files, and the refusal of a folder or MJCF that does not match) as its ``RL_Sim`` does
(``src/rl_sar/src/rl_sim_mujoco.cpp``, ``library/core/rl_sdk``): the observation of
``config.yaml``'s terms in its order (commands x commands_scale, IMU gyro x ang_vel_scale,
gravity rotated into the IMU's frame, joint angles about default_dof_pos, joint speeds x
dof_vel_scale, the last raw action) in the policy's joint order (``q[i] =
sensordata[joint_mapping[i]]``), clipped to clip_obs, into the history ``observations_history``
names (HIMLoco's: 6 frames, newest first), zeros before the first (``ObservationBuffer``,
priority ``time``; no history: the present frame alone); TorchScript inference every ``dt x
decimation`` s; ``target = default_dof_pos + action_scale x action``; torques ``kp (target - q) -
kd dq`` with ``rl_kp``, ``rl_kd`` (HIMLoco's Go2: 40, 1). Ours: the PD torque at every physics step of ``dt``
(0.005 s, legged_gym's, for a deterministic loop; rl_sar's threads run it at dt beside MuJoCo's own
real-time stepping), the robot first brought from its ``home`` key to default_dof_pos over 1 s
with ``fixed_kp``/``fixed_kd`` (rl_sar's get-up), the command then held; ``--start standing``:
the robot handed to the policy as our plant spawns it instead (the default pose at rest, at the
standing height), the start a comparison with ``deploy-run`` gives both loops (docs/soak.md).

A crossing: the base reaches ``CROSSED_X`` m along x (the tile's rim, 4 m from its centre) without
tipping past 1 rad or its height above the ground under it falling under 0.4 x the standing
height (the project's fall judges; the robot's standing height, :func:`standing_height`: its
import's, else the shipped robot's of its name, else its MJCF's ``home`` key's). ``--motors
ROBOT_DIR``: an imported robot's motors (effort limits, torque-speed lines at 25 degC, as the
plant applies them); ``--sensor-noise``: its white encoder, joint-speed and gyro noise. Usage::

    python -m sim2real.stacks.loops.himloco_terrain_loop RL_SAR_DIR UNITREE_MUJOCO_DIR \
        stairs_up:0.10 slope_up:15deg
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import mujoco
import numpy as np

from sim2real.eval.world.terrain import apply_terrain, parse_terrain
from sim2real.stacks.loops import rl_sar_robot

CROSSED_X = 4.0
#: m the robot is put above its key pose on a tile (a foot sphere started inside the height
#: field is held by its prisms' walls)
DROP = 0.03
#: rad, and share of the standing height: the project's fall judges
FALL_TILT, FALL_SHARE = 1.0, 0.4
#: rl_sar's key of the CLI's default policy
GO2_HIMLOCO = "go2/himloco"
#: ``run``'s starts: rl_sar's get-up, or our plant's standing spawn
START_KINDS = ("get-up", "standing")


def _model(
    unitree_mujoco: Path,
    terrain,
    seed: int,
    dt: float,
    plant_of: Path | None = None,
    key: str = GO2_HIMLOCO,
    cfg: dict | None = None,
    robot=None,
):
    """The MJCF of ``key``'s robot (:func:`sim2real.stacks.loops.rl_sar_robot.mjcf`) with a floor, the tile
    laid in; its missing visual meshes dropped; checked against ``cfg`` (rl_sar's keys) and
    ``robot`` (an import, :func:`sim2real.stacks.loops.rl_sar_robot.check_model`). ``plant_of``: an imported
    robot folder whose MJCF's integrator and joints' armature, damping and friction loss replace
    the MJCF's (the plant's joint dynamics on the policy's own loop).

    Raises:
        rl_sar_robot.Mismatch: the MJCF missing, or not what the loop or ``robot`` needs.
    """
    xml = rl_sar_robot.mjcf(unitree_mujoco, key)
    spec = rl_sar_robot.load_spec(xml)
    if plant_of is not None:
        ours = mujoco.MjModel.from_xml_path(str(next(Path(plant_of).glob("*.xml"))))
        spec.option.integrator = ours.opt.integrator
        for joint in spec.joints:
            if joint.type == mujoco.mjtJoint.mjJNT_HINGE:
                dof = ours.jnt_dofadr[ours.joint(joint.name).id]
                joint.armature = float(ours.dof_armature[dof])
                joint.damping = [float(ours.dof_damping[dof]), 0.0, 0.0]
                joint.frictionloss = float(ours.dof_frictionloss[dof])
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
    spec.option.timestep = dt
    ground = None
    if terrain is not None:
        ground = apply_terrain(spec, terrain, np.random.default_rng([seed, 0]))
    model = spec.compile()
    if cfg is not None:
        rl_sar_robot.check_model(model, cfg, xml, robot)
    return model, ground


def _motors(robot_dir: Path, model, noise: bool):
    """The torque clamp ``clamp(tau, dq)`` of ``robot_dir``'s motors in actuator order, and
    the noise sigmas (encoder rad, joint speed rad/s, gyro rad/s, gyro turn-on bias rad/s, the
    AHRS roll/pitch error rad and its correlation time s; zeros without ``noise``)."""
    from sim2real.robots.loading import load_robot
    from sim2real.robots.torque_speed import TorqueSpeedEnvelope

    robot = load_robot(robot_dir)
    index = {name: i for i, name in enumerate(robot.joint_names)}
    order = [index[model.joint(model.actuator_trnid[a, 0]).name] for a in range(model.nu)]
    envelope = TorqueSpeedEnvelope([robot.motors[i] for i in order])
    effort = np.asarray(robot.effort_limit, float)[order]
    hot = np.full(model.nu, 25.0)

    def clamp(tau, dq):
        lower, upper = envelope.limits(dq, effort, hot)
        return np.clip(tau, lower, upper)

    s = robot.config.sensors
    imu = s.imu
    sigmas = (
        s.encoder_noise_sigma,
        s.velocity_noise_sigma or 0.0,
        imu.gyro_noise_sigma,
        imu.gyro_bias_sigma,
        imu.orientation_sigma or 0.0,
        imu.orientation_tau or 1.0,
    )
    return clamp, np.asarray(sigmas if noise else (0.0,) * 5 + (1.0,), float)


def run(
    rl_sar: Path,
    unitree_mujoco: Path,
    tile: str | None,
    seconds: float,
    vx: float,
    seed=0,
    motors: Path | None = None,
    sensor_noise: bool = False,
    timestep: float | None = None,
    plant_of: Path | None = None,
    pushes=None,
    cross: bool = True,
    key: str = GO2_HIMLOCO,
    robot=None,
    stand: float = 0.0,
    start: str = "get-up",
):
    """One run on ``tile`` (``--terrain`` syntax, or a
    :class:`~sim2real.eval.world.terrain.TerrainDraw`; None: the plane): a dict of whether it
    crossed, the time, x reached, whether and when it fell, and ``start_base_m``: the base's x,
    y (m) and height above the ground under it when the policy takes over (after ``start``).
    ``pushes``: ``(robot, PushRanges)``,
    the soak's push schedule of ``seed`` (:class:`~sim2real.eval.world.pushes.DomainPushes`) on
    this loop's policy ticks after the get-up, pushing the model through ``robot``'s (an import
    of the same MJCF) push methods; the pushes' times (s) in ``push_times``. ``cross``:
    False, the run goes on past the tile's rim (``crossed`` stays False). ``motors``: an imported robot
    folder whose motors clamp the torques (and, with ``sensor_noise``, whose sensors' white
    noise the observation gets, drawn from ``seed``). ``timestep``: s, the physics step in
    place of rl_sar's ``dt`` (the PD law at every step, the policy at rl_sar's own rate).
    ``plant_of``: see :func:`_model`. ``guard_stop_s`` in the result: when our guard's
    hard-limit rule would have stopped the run (counted, not acted on). ``key``: rl_sar's
    ``<robot>/<policy>`` (:mod:`.rl_sar_robot`: its folder in ``rl_sar``, its MJCF in
    ``unitree_mujoco``); ``robot``: the import it is compared with (default ``pushes``' robot),
    whose base body, feet and joints its MJCF must have and whose standing height judges the
    fall (without one: :func:`standing_height`). ``stand``: s the policy runs with a zero command
    after the get-up before the command is given (its gait's phase at the tile's first step;
    ``seconds`` and the crossing's time count from the command). ``start``: ``get-up``
    (rl_sar's: the ``home`` key dropped ``DROP`` m onto the ground, brought to default_dof_pos
    over 1 s with ``fixed_kp``/``fixed_kd``), or ``standing`` (our plant's spawn, as
    ``deploy-run --backend sim`` starts: default_dof_pos, the base level at the standing height
    of :func:`standing_height`, above the ground at the tile's centre, at rest; the policy from
    the first step).

    Raises:
        rl_sar_robot.Mismatch: the folder, the MJCF or the robot do not match (one line).
    """
    import torch

    robot = pushes[0] if robot is None and pushes is not None else robot
    cfg, folder = rl_sar_robot.read_folder(rl_sar, key)
    standing = standing_height(key, robot, motors, unitree_mujoco)
    dt, decimation, n = float(cfg["dt"]), int(cfg["decimation"]), int(cfg["num_of_dofs"])
    if timestep is not None:  # the same policy period on a finer physics step
        decimation = int(round(dt * decimation / timestep))
        dt = float(timestep)
    terrain = None if tile in (None, "plane") else tile
    if isinstance(terrain, str):
        terrain = parse_terrain(terrain)
    model, ground = _model(unitree_mujoco, terrain, seed, dt, plant_of, key, cfg, robot)
    data = mujoco.MjData(model)
    clamp, sigma = None, np.array([0.0] * 5 + [1.0])
    if motors is not None:
        clamp, sigma = _motors(motors, model, sensor_noise)
    noise = np.random.default_rng([seed, 1])
    gyro_bias = noise.normal(0.0, 1.0, 3) * sigma[3]
    tilt = noise.normal(0.0, 1.0, 2) * sigma[4]  # the AHRS's roll and pitch errors, Gauss-Markov
    keep = math.exp(-dt * decimation / sigma[5])
    key = model.key("home").id
    mujoco.mj_resetDataKeyframe(model, data, key)
    if ground is not None:  # the key's base height above the ground at the start
        data.qpos[2] += float(ground.height_at(0.0, 0.0)) + DROP
    mujoco.mj_forward(model, data)
    policy = torch.jit.load(str(folder / cfg["model_name"])).eval()
    mapping = np.asarray(cfg["joint_mapping"])
    default = np.asarray(cfg["default_dof_pos"], float)
    scale = np.asarray(cfg["action_scale"], float)
    kp, kd = np.asarray(cfg["rl_kp"], float), np.asarray(cfg["rl_kd"], float)
    fkp, fkd = np.asarray(cfg["fixed_kp"], float), np.asarray(cfg["fixed_kd"], float)
    frames = list(cfg.get("observations_history") or [])  # rl_sar's ObservationBuffer: 0 newest
    history = np.zeros((max(frames, default=0) + 1, int(cfg["num_observations"])))
    action = np.zeros(n)
    quat_at = 3 * n

    def q_dq():
        s = data.sensordata
        return s[mapping], s[mapping + n]

    def torque(target, p, d):
        q, dq = q_dq()
        tau = np.zeros(n)
        tau[mapping] = p * (target - q) - d * dq
        if clamp is not None:  # the motors' limits at the actuators' own speeds
            tau = clamp(tau, data.qvel[model.jnt_dofadr[model.actuator_trnid[:, 0]]])
        data.ctrl[:] = tau

    if start not in START_KINDS:
        raise ValueError(f"start {start!r}: expected one of {START_KINDS}")
    get_up = int(1.0 / dt)
    if start == "standing":  # our plant's spawn: the default pose on the ground, at rest
        adr = model.jnt_qposadr[model.sensor_objid[:n]]  # the joint of each angle reading
        data.qpos[adr[mapping]] = default
        data.qpos[:7] = [0.0, 0.0, standing, 1.0, 0.0, 0.0, 0.0]
        if ground is not None:
            data.qpos[2] += float(ground.height_at(0.0, 0.0))
        data.qvel[:] = 0.0
        mujoco.mj_forward(model, data)
        get_up = 0
    start = q_dq()[0].copy()
    for k in range(get_up):  # rl_sar's get-up: the pose interpolated to default over 1 s
        torque(start + (default - start) * (k + 1) / get_up, fkp, fkd)
        mujoco.mj_step(model, data)
    command = np.array([vx, 0.0, 0.0])
    low = FALL_SHARE * standing
    asked, stand_steps = command.copy(), int(round(stand / dt))
    steps = int(seconds / dt) + stand_steps
    out = {"tile": tile, "crossed": False, "fell": False, "t_s": seconds}
    base = data.qpos[:3].copy()  # where the policy's first step finds the base
    base[2] -= 0.0 if ground is None else float(ground.height_at(base[0], base[1]))
    out["start_base_m"] = [float(v) for v in base]
    target = default.copy()
    # our guard's hard-limit rule on this loop's joint readings, counted, never acted on
    # (sim2real.deploy.safety.limits: past the range for 1 s, or 0.1 rad past for 0.1 s)
    lower, upper = (model.jnt_range[model.actuator_trnid[mapping, 0], i] for i in (0, 1))
    past_ticks = far_ticks = 0
    period = dt * decimation
    schedule = walk = base_pushes = None
    if pushes is not None:  # the soak's schedule on this loop's policy ticks (:mod:`.walk`)
        from sim2real.deploy.backends.sim.disturbances import SimDisturbances
        from sim2real.eval.world.pushes import DomainPushes
        from sim2real.stacks.loops.walk import Walk

        schedule = DomainPushes([seed], pushes[1], period)
        walk, base_pushes = Walk(), SimDisturbances(pushes[0], [model], [data])
    for k in range(steps):
        command = asked * (k >= stand_steps)
        if k % decimation == 0:
            q, dq = q_dq()
            over = np.maximum(lower - q, q - upper).max()
            past_ticks = past_ticks + 1 if over > 0.0 else 0
            far_ticks = far_ticks + 1 if over > 0.1 else 0
            if "guard_stop_s" not in out and (
                past_ticks > round(1.0 / period) or far_ticks > round(0.1 / period)
            ):
                out["guard_stop_s"] = k * dt
            q = q + noise.normal(0.0, 1.0, n) * sigma[0]
            dq = dq + noise.normal(0.0, 1.0, n) * sigma[1]
            s = data.sensordata
            w, x, y, z = s[quat_at : quat_at + 4]
            r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                          [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                          [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])  # fmt: skip
            tilt = keep * tilt + math.sqrt(1 - keep**2) * sigma[4] * noise.normal(0.0, 1.0, 2)
            cr, sr, cp, sp = (
                math.cos(tilt[0]),
                math.sin(tilt[0]),
                math.cos(tilt[1]),
                math.sin(tilt[1]),
            )
            error = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) @ np.array(
                [[1, 0, 0], [0, cr, -sr], [0, sr, cr]]
            )
            gravity = (r @ error).T @ np.array([0.0, 0.0, -1.0])
            gyro = s[quat_at + 4 : quat_at + 7] + noise.normal(0.0, 1.0, 3) * sigma[2] + gyro_bias
            terms = {  # rl_sar's ComputeObservation, in config.yaml's order
                "commands": command * np.asarray(cfg["commands_scale"]),
                "ang_vel": gyro * cfg["ang_vel_scale"],
                "gravity_vec": gravity,
                "dof_pos": (q - default) * cfg["dof_pos_scale"],
                "dof_vel": dq * cfg["dof_vel_scale"],
                "actions": action,
            }
            obs = np.concatenate([terms[t] for t in cfg["observations"]])
            obs = np.clip(obs, -cfg["clip_obs"], cfg["clip_obs"])
            history[1:] = history[:-1].copy()
            history[0] = obs
            x_in = history[frames] if frames else obs  # "time" priority: whole frames in turn
            with torch.no_grad():
                x_in = torch.as_tensor(x_in.reshape(1, -1), dtype=torch.float32)
                action = policy(x_in).numpy()[0].astype(float)
            action = np.clip(action, cfg["clip_actions_lower"], cfg["clip_actions_upper"])
            target = default + scale * action
        torque(target, kp, kd)
        mujoco.mj_step(model, data)
        base = data.qpos[:3]
        up = 1 - 2 * (data.qpos[4] ** 2 + data.qpos[5] ** 2)  # the base z axis' world z
        floor = 0.0 if ground is None else float(ground.height_at(base[0], base[1]))
        if math.acos(max(-1.0, min(1.0, up))) > FALL_TILT or base[2] - floor < low:
            out.update(fell=True, t_s=(k + 1 - stand_steps) * dt)
            break
        if cross and base[0] >= CROSSED_X:
            out.update(crossed=True, t_s=(k + 1 - stand_steps) * dt)
            break
        if schedule is not None and (k + 1) % decimation == 0:  # a policy tick's end: its push
            walk.ticks = (k + 1) // decimation
            schedule(walk, base_pushes)
    out["x_m"] = float(data.qpos[0])
    if schedule is not None:
        out["push_times"] = list(schedule.times[0])
    return out


def standing_height(key: str, robot=None, motors: Path | None = None, unitree_mujoco=None) -> float:
    """m, the standing height of rl_sar's robot of ``key`` (``<robot>/<policy>``), which judges
    its falls and places its ``standing`` start: the robot import given (``robot``, else
    ``motors``' import), else the shipped robot of that name (``sim2real/robots/<robot>``:
    go2's 0.3257 m), else the base height of the ``home`` key of its unitree_mujoco MJCF
    (:func:`.rl_sar_robot.mjcf`: b2.xml's 0.5 m): never another robot's.

    Raises:
        rl_sar_robot.Mismatch: none of these (the MJCF missing or without a ``home`` key).
    """
    import sim2real.robots
    from sim2real.robots.loading import load_robot

    if robot is None and motors is not None:
        robot = load_robot(motors)
    name = key.split("/")[0]
    if robot is None and (Path(sim2real.robots.__file__).parent / name / "robot.toml").is_file():
        robot = load_robot(name)
    if robot is not None:
        return float(robot.config.base.standing_height)
    xml = rl_sar_robot.mjcf(unitree_mujoco, key)
    model = rl_sar_robot.load_spec(xml).compile()
    if "home" not in [model.key(i).name for i in range(model.nkey)]:
        raise rl_sar_robot.Mismatch(f"{xml}: keyframe 'home': none, and no import of '{name}'")
    return float(model.key("home").qpos[2])


def start_delay(seed: int, stand_max: float) -> float:
    """s a run of ``seed`` stands before its command (``--stand-max``): U(0, ``stand_max``)
    from ``numpy.random.default_rng([seed, 3])``; 0 without one."""
    if stand_max <= 0.0:
        return 0.0
    return float(np.random.default_rng([seed, 3]).uniform(0.0, stand_max))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m sim2real.stacks.loops.himloco_terrain_loop")
    p.add_argument("rl_sar", type=Path, help="an rl_sar checkout (policy/<robot>/<policy>)")
    p.add_argument("unitree_mujoco", type=Path, help="a unitree_mujoco checkout")
    p.add_argument("tiles", nargs="+", help="--terrain tiles (stairs_up:0.10, slope_up:15deg)")
    p.add_argument("--seconds", type=float, default=16.0)
    p.add_argument("--vx", type=float, default=0.5)
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--motors", type=Path, help="an imported robot folder: its motors' limits")
    p.add_argument("--sensor-noise", action="store_true", help="--motors' sensor noise")
    p.add_argument("--timestep", type=float, help="s, the physics step (default rl_sar's dt)")
    p.add_argument("--plant-of", type=Path, help="an imported robot: its integrator, joints")
    p.add_argument("--policy", default=GO2_HIMLOCO, help="rl_sar's key <robot>/<policy>")
    p.add_argument(
        "--stand-max", type=float, default=0.0,
        help="s: each seed stands U(0, S) s (zero command) after the get-up before walking",
    )  # fmt: skip
    p.add_argument(
        "--start", choices=START_KINDS, default="get-up",
        help="get-up: rl_sar's (the home key dropped onto the ground, 1 s to the default pose); "
        "standing: our plant's spawn (the default pose on the ground at the standing height)",
    )  # fmt: skip
    args = p.parse_args(argv)
    if args.sensor_noise and args.motors is None:
        p.error("--sensor-noise needs --motors (the robot whose sensors' noise it draws)")
    for tile in args.tiles:
        runs = [
            run(
                args.rl_sar,
                args.unitree_mujoco,
                tile,
                args.seconds,
                args.vx,
                s,
                args.motors,
                args.sensor_noise,
                args.timestep,
                args.plant_of,
                key=args.policy,
                stand=start_delay(s, args.stand_max),
                start=args.start,
            )  # fmt: skip
            for s in range(args.first_seed, args.first_seed + args.seeds)
        ]
        crossed = sum(r["crossed"] for r in runs)
        each = [
            f"x {r['x_m']:.2f} m{' fell' if r['fell'] else ''} at {r['t_s']:.2f} s"
            + (f" (hard-limit stop at {r['guard_stop_s']:.2f} s)" if "guard_stop_s" in r else "")
            for r in runs
        ]
        print(f"{tile}: crossed {crossed}/{len(runs)}; " + "; ".join(each))


if __name__ == "__main__":
    main()
