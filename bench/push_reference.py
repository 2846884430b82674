"""Legged policies under pushes: our runtime beside each policy's own loop on the true state.

``python -m bench.push_reference [--robots go2,h1,h1_2] [--user NAME=ROBOT_DIR,POLICY[,DEPLOY_YAML,
MOTION_PT]] [--domain NAME=RANGES] [--seeds 0-99] [--seconds 60] [--apply force]
[--rl-sar NAME=RL_SAR,UNITREE_MUJOCO --terrain KIND:SIZE|RANGES.toml]``

Does a policy fall under pushes because of our runtime, or would it fall in its own stack's loop
too? Each seed's push sequence runs, walking at ``--command``, for ``--seconds`` in the policy's
own loop and in ours (:mod:`bench.push_loops`): the shipped go2 (its loop: its spec fed the true
state), unitree_rl_gym's H1 and H1-2 (their ``deploy_mujoco.py`` loop with the published
``motion.pt``), and a user's robot and policy (``--user``: with unitree_rl_gym's deploy yaml and
``motion.pt``, their loop; without, the truth-fed loop of the ONNX file's spec: an mjlab export).
A whole-body tracking policy (``--tracking NAME=ROBOT_DIR,RL_SAR_FOLDER``: rl_sar's folder with
``policy.pt`` and the ``policy.onnx`` policy-export wrote beside it) plays its clip once instead of
walking, in rl_sar's loop and in ours with the tracking task (:mod:`bench.push_tracking`).

The pushes are the policy's training domain's (the ONNX file's ``training_domain``, or
``--domain NAME=FILE``'s ``[pushes]``), else legged_gym's push at ``--max-velocity`` every 5 s;
as forces over the push's window (the soak's default) or, ``--apply velocity_hidden_from_imu``,
the velocity set as the training stacks do; ``--no-pushes``: none (walking alone). Printed per
policy and loop: pushes survived (before the fatal one), falls and falls per hour walked, the
ticks whose end found a joint of the true state past its hard limit (and per push: what a guard
keeping the range must prevent), interventions per RUNNING tick (ours; the own loops have no
guard; in brackets those of the ticks more than ``QUIET_AFTER_PUSH`` after a push), the stops
of a robot the truth had upright, and the base estimate's planar
velocity error in the second after a push; then the paired comparison per seed (same fatal push,
ours earlier, ours later) with a two-sided sign test. A run of ours whose tick raised (a safe
stop Ruckig could not plan) ends there, counted as a fall and named ``raised`` in the table.
``--rl-sar``: :func:`rl_sar_entry`; a base-velocity policy's more rows: :data:`ON_OUR_PLANT`.
Exit codes: 0 the table printed; 2 bad input (a flag, a file), one line naming the flag.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bench.push_loops import (  # noqa: F401 (bench.estimation imports them from here)
    observes_base_velocity,
    plant_loop,
    runtime_loop,
    truth_loop,
    unitree_loop,
)
from bench.push_table import sign_test, summary, survived, table, terrain_table  # noqa: F401
from sim2real.robots.errors import Sim2RealError
from sim2real.stacks.loops.bare import Run
from sim2real.stacks.loops.unitree_rl_gym import load_torchscript

PROG = "python -m bench.push_reference"
#: exit code of bad input (module docstring)
BAD_INPUT = 2
ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data" / "unitree_rl_gym"
#: s between pushes of a policy without a training domain's (unitree_rl_gym's humanoid configs'
#: ``push_interval_s``)
PUSH_INTERVAL = 5.0
#: m/s, legged_gym's ``max_push_vel_xy`` default (``LeggedRobotCfg.domain_rand``)
MAX_PUSH_VELOCITY = 1.0


@dataclass(frozen=True)
class Entry:
    """A policy of the benchmark: its name, robot (name or folder), ONNX file, and, for
    unitree_rl_gym's loop, its deploy yaml and TorchScript policy (None: the truth-fed loop of
    the ONNX's spec); ``domain``: a ranges file whose ``[pushes]`` it runs (None: the ONNX's);
    ``tracking``: a whole-body tracking policy's rl_sar folder (its clip played in rl_sar's loop
    and ours, :mod:`bench.push_tracking`; None: a walking policy); ``rl_sar``: (rl_sar, unitree_mujoco)
    checkouts whose HIMLoco loop is its own (:mod:`sim2real.stacks.loops.himloco_terrain_loop`)."""

    name: str
    robot: str
    policy: Path
    config: Path | None = None
    torchscript: Path | None = None
    domain: Path | None = None
    tracking: Path | None = None
    rl_sar: tuple[Path, Path] | None = None
    rl_sar_key: str | None = None

    @property
    def own_loop(self) -> str:
        if self.tracking:
            return "rl_sar tracking"
        if self.rl_sar:
            robot = str(self.rl_sar_key).split("/")[0]
            return f"rl_sar {self.rl_sar_key} on {robot}.xml"
        return "unitree_rl_gym" if self.config else "truth-fed spec"


class BadInput(ValueError):
    """A bad flag or file: one line naming the flag and the value expected (exit ``BAD_INPUT``)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, not argparse's usage and exit
        raise BadInput(message)


SHIPPED = {
    "go2": Entry("go2", "go2", ROOT / "sim2real" / "policies" / "go2.onnx"),
    **{
        r: Entry(r, r, DATA / r / f"{r}.onnx", DATA / r / f"{r}.yaml", DATA / r / "motion.pt")
        for r in ("h1", "h1_2")
    },
}


def push_ranges(entry: Entry, robot, args):
    """The :class:`~sim2real.eval.world.pushes.PushRanges` of ``entry``'s runs (module
    docstring), with ``--max-velocity`` (legged_gym's pushes), ``--apply`` and ``--window``."""
    from sim2real.eval.world.domain import training_domain
    from sim2real.eval.world.pushes import PushRanges
    from sim2real.eval.world.ranges_file import load_ranges, load_ranges_text

    if args.no_pushes:
        return None
    pushes = None
    if entry.domain is not None:
        pushes = load_ranges(entry.domain, robot).pushes
    else:
        text = training_domain(entry.policy)
        if text is not None:
            pushes = load_ranges_text(text, f"{entry.policy} training_domain", robot).pushes
    if pushes is None:
        pushes = PushRanges(interval=PUSH_INTERVAL, max_velocity=MAX_PUSH_VELOCITY)
    if args.max_velocity is not None and pushes.legacy:
        pushes = replace(pushes, max_velocity=args.max_velocity)
    if args.apply is not None:
        pushes = replace(pushes, apply=args.apply)
    if args.window is not None:
        pushes = replace(pushes, window=args.window)
    return pushes


def _load(entry: Entry):
    """(robot with the policy's drive, fresh OnnxPolicy) of ``entry``."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.drive import drive_robot
    from sim2real.robots import load_robot

    robot = load_robot(entry.robot)
    robot, _ = drive_robot(robot, OnnxPolicy(entry.policy, robot).spec)
    return robot, OnnxPolicy(entry.policy, robot)


def terrain_of(seed: int, args):
    """The :class:`~sim2real.eval.world.terrain.TerrainDraw` of seed ``seed``'s runs (None: the
    plane): ``--terrain KIND:SIZE`` (or ``KIND@LEVEL``) for every seed, or a ranges file's
    ``[terrain]`` drawn per seed (kind and level, as a soak session draws them); either laid out
    in ``--terrain-tiles`` x ``--terrain-tiles`` tiles of its kind and level (a file's
    ``walk = "curriculum"``, a soak's, is not walked here)."""
    from sim2real.eval.world.ranges_file import read_overrides
    from sim2real.eval.world.terrain import TerrainRanges, parse_terrain, sample_terrain

    text = getattr(args, "terrain", None)
    if text is None:
        return None
    tiles = getattr(args, "terrain_tiles", 3)
    if text.endswith(".toml"):
        ranges = read_overrides(text).get("terrain")
        if ranges is None:
            raise BadInput(f"--terrain {text}: the file has no [terrain] table")
        # one tile's grid per seed: a push run has no episodes (a curriculum walk is a soak's)
        ranges = TerrainRanges(**(ranges | {"tiles": tiles, "walk": "grid"}))
        return sample_terrain(np.random.default_rng([seed, 2]), ranges)
    return parse_terrain(text, TerrainRanges(tiles=tiles))


def check_terrain(seeds: list[int], args) -> None:
    """Every seed's ``--terrain`` draw, made once before any run.

    Raises:
        BadInput: naming ``--terrain`` and what is wrong (an unknown kind, a malformed size, a
            ranges file that cannot be read or has no ``[terrain]``), or ``--terrain-tiles``.
    """
    if args.terrain is None:
        return
    if args.terrain_tiles < 1 or args.terrain_tiles % 2 == 0:
        raise BadInput(f"--terrain-tiles {args.terrain_tiles}: expected an odd count >= 1")
    for seed in seeds:
        try:
            terrain_of(seed, args)
        except BadInput:
            raise
        except (ValueError, TypeError) as e:  # parse_terrain, RangesError, TerrainRanges' keys
            said = str(e) if str(e).startswith("--terrain") else f"--terrain {args.terrain}: {e}"
            raise BadInput(said) from None


def rl_sar_run(entry: Entry, robot, seed: int, args, pushes, terrain) -> Run:
    """rl_sar's own loop of ``entry``'s robot
    (:mod:`sim2real.stacks.loops.himloco_terrain_loop`: rl_sar's runtime on unitree_mujoco's MJCF
    of ``entry.rl_sar_key``'s robot, true state) under the same pushes on the same tiles, as a
    :class:`Run`."""
    from sim2real.deploy.core.stacks import STACK_REGISTRY

    run = STACK_REGISTRY.get("rl_sar").face("own_loop")  # sim2real/stacks/rl_sar.py
    vx = float(args.command.split(",")[0])  # vy and yaw 0 (checked by _entries)
    ours = {}
    if getattr(args, "rl_sar_plant", False):  # like against like: our plant, motors, sensors
        folder = Path(entry.robot)
        ours = {"motors": folder, "sensor_noise": True, "plant_of": folder}
        ours["timestep"] = float(robot.plant_model("torque").opt.timestep)
    out = run(
        entry.rl_sar[0], entry.rl_sar[1], terrain, args.seconds, vx, seed,
        pushes=None if pushes is None else (robot, pushes), cross=False,
        key=entry.rl_sar_key, robot=robot, **ours,
    )  # fmt: skip
    fell = out["t_s"] if out["fell"] else None
    return Run(fell_at=fell, cause="fall" if out["fell"] else None, walked=out["t_s"],
               pushes=out.get("push_times", []))  # fmt: skip


#: The more rows of a policy that observes the base's linear velocity (``base_linear_velocity``)
#: run truth-fed (``--user`` without a deploy yaml): its own loop on our plant (``SimBackend``,
#: the runtime's drives and sensors) fed the truth, and fed our base estimate
#: (:func:`bench.push_loops.plant_loop`): what the estimate costs it, like with like.
ON_OUR_PLANT = ("own on our plant, fed the truth", "own on our plant, fed our estimate")


def run_seed(entry: Entry, seed: int, args) -> tuple[Run, Run, dict[str, Run]]:
    """(own loop, ours, more own loops by row name) of ``entry`` on push sequence ``seed`` (on
    ``--terrain``'s tiles); the more: ``ON_OUR_PLANT``'s for a truth-fed policy that observes
    the base's linear velocity, else none."""
    import yaml

    robot, policy = _load(entry)
    pushes = push_ranges(entry, robot, args)
    if entry.tracking is not None:  # a clip played once in each loop
        from bench.push_tracking import tracking_runtime_loop
        from sim2real.stacks.loops.rl_sar_pushed import rl_sar_loop

        own = rl_sar_loop(robot, entry.tracking, seed, args.seconds, pushes)
        return own, tracking_runtime_loop(robot, policy, seed, args.seconds, pushes), {}
    command = [float(x) for x in args.command.split(",")]
    terrain, more = terrain_of(seed, args), {}
    if entry.rl_sar is not None:
        own = rl_sar_run(entry, robot, seed, args, pushes, terrain)
        ours = runtime_loop(robot, policy, seed, args.seconds, pushes, command, terrain)
        return own, ours, {}
    if entry.config is not None:
        cfg = yaml.safe_load(Path(entry.config).read_text())
        net = load_torchscript(entry.torchscript)
        own = unitree_loop(robot, cfg, net, seed, args.seconds, pushes, command)
    else:
        own = truth_loop(robot, policy, seed, args.seconds, pushes, command)
        if observes_base_velocity(policy):  # what the estimate costs it, on one plant
            for name, estimate in zip(ON_OUR_PLANT, (False, True), strict=True):
                _, policy = _load(entry)
                run = plant_loop(robot, policy, seed, args.seconds, pushes, command, estimate)
                more[name] = run
        _, policy = _load(entry)  # fresh: a recurrent policy's memory
    ours = runtime_loop(robot, policy, seed, args.seconds, pushes, command)
    return own, ours, more


def _entries(args, p: argparse.ArgumentParser) -> list[Entry]:
    """The policies of ``--robots`` and ``--user``, with ``--domain``'s files."""
    domains = {}
    for item in args.domain:
        name, _, path = item.partition("=")
        if not path:
            p.error(f"--domain {item!r}: expected NAME=RANGES_FILE")
        if not Path(path).is_file():
            p.error(f"--domain {item!r}: {path}: no such file")
        domains[name] = Path(path)
    out = []
    for name in [n for n in args.robots.split(",") if n]:
        if name not in SHIPPED:
            p.error(f"--robots: {name!r} is not one of {sorted(SHIPPED)}")
        out.append(SHIPPED[name])
    for item in args.user:
        name, _, rest = item.partition("=")
        parts = rest.split(",")
        if not name or len(parts) not in (2, 4):
            p.error(f"--user {item!r}: expected NAME=ROBOT_DIR,POLICY[,DEPLOY_YAML,MOTION_PT]")
        for path in parts[1:]:  # ROBOT_DIR may name a shipped robot (load_robot's)
            if not Path(path).is_file():
                p.error(f"--user {item!r}: {path}: no such file")
        files = [Path(x) for x in parts[2:]] + [None, None]
        out.append(Entry(name, parts[0], Path(parts[1]), files[0], files[1]))
    for item in getattr(args, "tracking", []):  # bench.guard_replay has no --tracking
        name, _, rest = item.partition("=")
        parts = rest.split(",")
        if not name or len(parts) != 2:
            p.error(f"--tracking {item!r}: expected NAME=ROBOT_DIR,RL_SAR_FOLDER")
        folder = Path(parts[1])
        if not (folder / "policy.onnx").is_file():
            p.error(f"--tracking {item!r}: {folder / 'policy.onnx'}: no such file")
        out.append(Entry(name, parts[0], folder / "policy.onnx", tracking=folder))
    unknown = set(domains) - {e.name for e in out}
    if unknown:
        p.error(f"--domain: {sorted(unknown)} name no policy of the run")
    out = [replace(e, domain=domains.get(e.name)) for e in out]
    loops = {}
    for item in getattr(args, "rl_sar", []):
        name, _, rest = item.partition("=")
        parts = rest.split(",")
        users = {e.name for e in out if e.config is None and e.tracking is None}
        if not name or len(parts) != 2 or name not in users:
            p.error(
                f"--rl-sar {item!r}: expected NAME=RL_SAR_DIR,UNITREE_MUJOCO_DIR of a "
                "--user NAME=ROBOT_DIR,POLICY"
            )
        loops[name] = (Path(parts[0]), Path(parts[1]))
    out = [rl_sar_entry(e, loops[e.name], args, p.error) if e.name in loops else e for e in out]
    if getattr(args, "terrain", None) is not None and any(e.rl_sar is None for e in out):
        p.error(
            f"--terrain {args.terrain}: only for --rl-sar policies (their own loop lays the "
            f"tiles too); {[e.name for e in out if e.rl_sar is None]} have none"
        )
    return out


def rl_sar_entry(entry: Entry, dirs: tuple[Path, Path], args, error: Callable) -> Entry:
    """``entry`` with its rl_sar own loop (``--rl-sar NAME=RL_SAR_DIR,UNITREE_MUJOCO_DIR``):
    rl_sar's MuJoCo loop of the robot given (:mod:`sim2real.stacks.loops.himloco_terrain_loop`), the policy
    folder ``RL_SAR_DIR/policy/<robot>/<policy>`` of the key of the rl_sar config.yaml beside its
    ONNX file (its TorchScript, joint mapping, default pose, gains, scales, decimation) on
    unitree_mujoco's ``unitree_robots/<robot>/<robot>.xml``, which must hold the ``--user``
    import's base body, feet and joints (:mod:`sim2real.stacks.loops.rl_sar_robot`); ``error(message)`` for a
    mismatch (one line naming ``--rl-sar`` and what is missing)."""
    from sim2real.robots import load_robot
    from sim2real.stacks.loops import rl_sar_robot

    try:
        key = rl_sar_robot.policy_key(entry.policy)
        rl_sar_robot.match(dirs[0], dirs[1], key, load_robot(entry.robot))
    except (rl_sar_robot.Mismatch, Sim2RealError) as e:
        error(f"--rl-sar {entry.name}: {e}")
    command = args.command.split(",")
    if any(float(x) for x in command[1:]):
        error(f"--rl-sar {entry.name}: rl_sar's loop walks at vx only; --command {args.command}")
    return replace(entry, rl_sar=dirs, rl_sar_key=key)


def main(argv: list[str] | None = None) -> int:
    """The benchmark (module docstring); returns its exit code (0, or ``BAD_INPUT`` with one
    line on stderr)."""
    try:
        return _main(argv)
    except BadInput as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return BAD_INPUT


def parser() -> argparse.ArgumentParser:
    """The benchmark's flags; a bad one raises :class:`BadInput` (one line, no usage)."""
    p = _Parser(prog=PROG, description=__doc__)
    p.add_argument("--robots", default="go2,h1,h1_2", help="shipped policies (go2, h1, h1_2)")
    p.add_argument("--user", action="append", default=[], metavar="NAME=ROBOT,POLICY[,YAML,PT]")
    p.add_argument(
        "--tracking", action="append", default=[], metavar="NAME=ROBOT,RL_SAR_FOLDER",
        help="a whole-body tracking policy's rl_sar folder: its clip once per run",
    )  # fmt: skip
    p.add_argument("--domain", action="append", default=[], metavar="NAME=RANGES_FILE")
    p.add_argument("--seeds", default="0-99", help="first-last push sequences")
    p.add_argument("--seconds", type=float, default=60.0, help="s walked per run (a clip: at most)")
    p.add_argument("--command", default="0.5,0,0", help="vx,vy,yaw rate (m/s, rad/s)")
    p.add_argument("--max-velocity", type=float, default=None, help="legged_gym's pushes, m/s")
    p.add_argument("--apply", choices=("force", "velocity_hidden_from_imu"), default=None)
    p.add_argument("--no-pushes", action="store_true", help="walk without pushes")
    p.add_argument("--window", type=float, default=None, help="s, a force push's duration")
    p.add_argument(
        "--rl-sar", action="append", default=[], metavar="NAME=RL_SAR_DIR,UNITREE_MUJOCO_DIR",
        help="a --user's own loop: rl_sar's loop of its robot (sim2real.stacks.loops.himloco_terrain_loop)",
    )  # fmt: skip
    p.add_argument(
        "--terrain", default=None, metavar="KIND:SIZE|KIND@LEVEL|RANGES.toml",
        help="both loops on legged_gym tiles (--rl-sar policies): one tile, or a ranges file's "
        "[terrain] drawn per seed",
    )  # fmt: skip
    p.add_argument("--terrain-tiles", type=int, default=3, help="tiles per side (odd)")
    p.add_argument(
        "--rl-sar-plant", action="store_true",
        help="the --rl-sar loop on our plant: the robot folder's motors, sensor noise, physics "
        "step, integrator and joints (sim2real.stacks.loops.himloco_terrain_loop --motors --sensor-noise "
        "--plant-of --timestep)",
    )  # fmt: skip
    p.add_argument("--jobs", type=int, default=1, help="processes")
    p.add_argument("--verbose", action="store_true", help="a line per seed")
    return p


def _seeds(text: str) -> list[int]:
    """``--seeds FIRST-LAST`` (or one seed) as a list."""
    lo, _, hi = text.partition("-")
    try:
        first, last = int(lo), int(hi or lo)
    except ValueError:
        raise BadInput(f"--seeds {text!r}: expected FIRST-LAST (integers), e.g. 0-99") from None
    if last < first:
        raise BadInput(f"--seeds {text!r}: expected FIRST <= LAST")
    return list(range(first, last + 1))


def _check_command(text: str) -> None:
    """``--command vx,vy,yaw``: three numbers."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3:
        raise BadInput(f"--command {text!r}: expected VX,VY,YAW (m/s, m/s, rad/s), e.g. 0.5,0,0")


def _main(argv: list[str] | None) -> int:
    p = parser()
    a = p.parse_args(argv)
    _check_command(a.command)
    seeds = _seeds(a.seeds)
    entries = _entries(a, p)
    check_terrain(seeds, a)
    for e in entries:  # the robot and policy load, and their pushes, before any run
        try:
            robot, _ = _load(e)
            push_ranges(e, robot, a)
        except Sim2RealError as exc:
            raise BadInput(f"{e.name}: {exc}") from None
    jobs = [(e, s) for e in entries for s in seeds]
    results = {e.name: (e, [], [], {}) for e in entries}
    pool = ProcessPoolExecutor(a.jobs) if a.jobs > 1 else None
    if pool:
        done = pool.map(run_seed, [e for e, _ in jobs], [s for _, s in jobs], [a] * len(jobs))
    for e, s in jobs:
        own, ours, more = next(done) if pool else run_seed(e, s, a)
        results[e.name][1].append(own)
        results[e.name][2].append(ours)
        for row, run in more.items():
            results[e.name][3].setdefault(row, []).append(run)
        if a.verbose:
            where = "" if a.terrain is None else f" [{terrain_of(s, a).label}]"
            print(
                f"{e.name} seed {s:3d}{where}: own fell at {own.fell_at}, ours {ours.fell_at} "
                f"({ours.cause}); pushes {survived(own)} / {survived(ours)}",
                file=sys.stderr,
                flush=True,
            )
    if pool:
        pool.shutdown()
    print(f"seeds {a.seeds}, {a.seconds:g} s each, command {a.command}")
    for e in entries:
        robot, _ = _load(e)
        once = f"its clip once (at most {a.seconds:g} s), not --command; " if e.tracking else ""
        print(f"{e.name}: {once}pushes {push_ranges(e, robot, a)}")
    print("\n".join(table(results, a)))
    if a.terrain is not None:
        kinds = [terrain_of(s, a).kind for s in seeds]
        print("\n".join(terrain_table(results, kinds)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
