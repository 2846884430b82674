"""The robot of rl_sar's own MuJoCo loop (:mod:`.himloco_terrain_loop`): its policy folder,
its MJCF, and whether they are the robot a run of ours is compared with.

rl_sar (fan-ziqi/rl_sar e384912) names a policy by its config key ``<robot>/<policy>``
(``go2/himloco``, ``b2/robot_lab``): ``RL::ReadYaml`` reads ``policy/<robot>/base.yaml`` (the key
``<robot>``) and ``policy/<robot>/<policy>/config.yaml`` (the key ``<robot>/<policy>``), the
second's keys over the first's, and ``InitRL`` loads ``model_name`` from the policy folder.
``RL_Sim`` (``src/rl_sar/src/rl_sim_mujoco.cpp``) reads the MJCF's ``sensordata`` by index: motor
``i``'s angle at ``joint_mapping[i]``, its speed ``num_of_dofs`` later, the IMU's quaternion at
``3 num_of_dofs`` and its gyro 4 after (unitree_mujoco's sensor layout: the joints' angles, speeds
and torques, then ``framequat``, ``gyro``). The MJCF here is unitree_mujoco's
``unitree_robots/<robot>/<robot>.xml`` (rl_sar's own ``rl_sar_zoo`` scenes are not in its
repository), started from its ``home`` key.

A folder or MJCF that is not the robot's is refused with :class:`Mismatch`, one line naming what
is missing; a robot import (:func:`sim2real.robots.load_robot`) given beside it must find its base
body, its feet and its joints in that MJCF (the pushes act on its base body).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import yaml

#: rl_sar's observation terms this loop computes (``RL::ComputeObservation``; ``lin_vel`` needs a
#: velocity rl_sar's MuJoCo loop does not read from a sensor)
TERMS = ("commands", "ang_vel", "gravity_vec", "dof_pos", "dof_vel", "actions")


class Mismatch(ValueError):
    """The rl_sar folder, its MJCF or the robot import do not match: one line naming what is
    missing (``python -m bench.push_reference`` exits 2 with it)."""


def _sole(path: Path, key: str | None = None) -> tuple[str, dict]:
    """(key, mapping) of the one-key YAML file ``path`` (its key must be ``key`` if given)."""
    if not path.is_file():
        raise Mismatch(f"{path}: no such file")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise Mismatch(f"{path}: not YAML ({str(e).splitlines()[0]})") from None
    if not (isinstance(doc, dict) and len(doc) == 1 and isinstance(next(iter(doc.values())), dict)):
        raise Mismatch(f"{path}: expected one mapping under rl_sar's key")
    found, value = next(iter(doc.items()))
    if key is not None and found != key:
        raise Mismatch(f"{path}: key {found!r}, expected {key!r}")
    return str(found), value


def policy_key(policy: Path) -> str:
    """rl_sar's key ``<robot>/<policy>`` of the config.yaml beside ``policy`` (an ONNX file
    policy-export wrote in an rl_sar policy folder).

    Raises:
        Mismatch: no rl_sar config.yaml beside it, or a key that is not ``<robot>/<policy>``.
    """
    config = Path(policy).parent / "config.yaml"
    if not config.is_file():
        raise Mismatch(
            f"{policy}: no rl_sar config.yaml beside it (expected the ONNX file policy-export "
            "wrote in rl_sar's policy/<robot>/<policy>/)"
        )
    key, _ = _sole(config)
    if len(key.split("/")) != 2:
        raise Mismatch(f"{config}: key {key!r}, expected rl_sar's '<robot>/<policy>'")
    return key


def read_folder(rl_sar: Path, key: str) -> tuple[dict, Path]:
    """(the keys rl_sar reads for ``key``: config.yaml's over base.yaml's, the policy folder).

    Raises:
        Mismatch: a file missing (the folder, base.yaml, the TorchScript ``model_name``), a
            wheeled robot (``wheel_indices``), an observation term or history this loop does
            not compute; each naming the file and key.
    """
    robot = key.split("/")[0]
    folder = Path(rl_sar) / "policy" / key
    if not folder.is_dir():
        raise Mismatch(f"{folder}: no such rl_sar policy folder (for the policy's key {key!r})")
    _, base = _sole(Path(rl_sar) / "policy" / robot / "base.yaml", robot)
    _, cfg = _sole(folder / "config.yaml", key)
    cfg = base | cfg
    where = folder / "config.yaml"
    missing = [k for k in ("model_name", "observations", "joint_mapping", "default_dof_pos",
                           "dt", "decimation", "num_of_dofs") if k not in cfg]  # fmt: skip
    if missing:
        raise Mismatch(f"{where}: no {missing[0]!r} (nor in {robot}/base.yaml)")
    if not (folder / str(cfg["model_name"])).is_file():
        raise Mismatch(f"{where}: model_name {cfg['model_name']!r}: no such file in {folder}")
    if cfg.get("wheel_indices"):
        raise Mismatch(
            f"{where}: wheel_indices {cfg['wheel_indices']}: a wheeled robot (legs only)"
        )
    other = [t for t in cfg["observations"] if t not in TERMS]
    if other:
        raise Mismatch(f"{where}: observation {other[0]!r}: expected terms of {list(TERMS)}")
    if cfg.get("observations_history") and cfg.get("observations_history_priority") != "time":
        raise Mismatch(
            f"{where}: observations_history_priority "
            f"{cfg.get('observations_history_priority')!r}: expected 'time'"
        )
    return cfg, folder


def mjcf(unitree_mujoco: Path, key: str) -> Path:
    """unitree_mujoco's ``unitree_robots/<robot>/<robot>.xml`` of ``key``'s robot.

    Raises:
        Mismatch: no such file.
    """
    robot = key.split("/")[0]
    path = Path(unitree_mujoco) / "unitree_robots" / robot / f"{robot}.xml"
    if not path.is_file():
        raise Mismatch(f"{path}: no such file (unitree_mujoco's MJCF of rl_sar's {robot!r})")
    return path


def load_spec(xml: Path) -> mujoco.MjSpec:
    """``xml``'s spec with its missing or empty meshes and their geoms dropped (a checkout's
    large files may be absent)."""
    spec = mujoco.MjSpec.from_file(str(xml))
    assets = xml.parent / (spec.meshdir or "")
    for mesh in list(spec.meshes):
        path = assets / mesh.file
        if not path.is_file() or path.stat().st_size == 0:
            for g in [g for g in spec.geoms if g.meshname == mesh.name]:
                spec.delete(g)
            spec.delete(mesh)
    return spec


def check_model(model: mujoco.MjModel, cfg: dict, xml: Path, robot=None) -> None:
    """That ``model`` (compiled from ``xml``) is what rl_sar's loop reads for ``cfg`` and, if
    given, ``robot``'s (an import): a free base, ``num_of_dofs`` motors, the sensors at rl_sar's
    indices, the ``home`` key; the import's base body, its feet's bodies (the bodies of its
    ``[base] feet`` sites in its own MJCF) and its joints.

    Raises:
        Mismatch: naming the first thing missing.
    """
    n = int(cfg["num_of_dofs"])
    if model.njnt == 0 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
        raise Mismatch(f"{xml}: no free joint first (a floating base expected)")
    if model.nu != n:
        raise Mismatch(f"{xml}: {model.nu} actuators, config num_of_dofs {n}")
    kinds = [
        (0, mujoco.mjtSensor.mjSENS_JOINTPOS, "jointpos"),
        (n, mujoco.mjtSensor.mjSENS_JOINTVEL, "jointvel"),
        (3 * n, mujoco.mjtSensor.mjSENS_FRAMEQUAT, "framequat"),
        (3 * n + 1, mujoco.mjtSensor.mjSENS_GYRO, "gyro"),
    ]
    for at, kind, name in kinds:
        if model.nsensor <= at or model.sensor_type[at] != kind:
            raise Mismatch(f"{xml}: sensor {at} is not a {name} (rl_sar reads sensordata by index)")
    if model.nkey == 0 or "home" not in [model.key(k).name for k in range(model.nkey)]:
        raise Mismatch(f"{xml}: no keyframe 'home' (the loop's start)")
    if robot is None:
        return
    base, own = robot.config.base, robot.mj_model
    feet = [own.body(own.site(f).bodyid[0]).name for f in base.feet]  # the foot sites' bodies
    names = [("body", base.body), *[("body", f) for f in feet]]
    names += [("joint", j) for j in robot.joint_names]
    lookup = {"body": mujoco.mjtObj.mjOBJ_BODY, "joint": mujoco.mjtObj.mjOBJ_JOINT}
    for kind, name in names:
        if mujoco.mj_name2id(model, lookup[kind], name) < 0:
            raise Mismatch(f"{xml}: no {kind} {name!r} of robot {robot.name!r} (not its MJCF?)")


def match(rl_sar: Path, unitree_mujoco: Path, key: str, robot=None) -> None:
    """That rl_sar's folder of ``key``, unitree_mujoco's MJCF of its robot and ``robot`` (an
    import, optional) make one robot's own loop (:func:`read_folder`, :func:`mjcf`,
    :func:`check_model`), before any run.

    Raises:
        Mismatch: naming the first thing missing.
    """
    cfg, _ = read_folder(rl_sar, key)
    xml = mjcf(unitree_mujoco, key)
    try:
        model = load_spec(xml).compile()
    except ValueError as e:  # MuJoCo's compile error
        raise Mismatch(f"{xml}: {str(e).splitlines()[0]}") from None
    check_model(model, cfg, xml, robot)
