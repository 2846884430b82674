"""``python -m sim2real.deploy.harness.ros2_hil``: deploy-run through the ros2 backend against the
ros2_control emulator, then the same run on the simulated plant, side by side.

Starts the emulator (``python -m sim2real.deploy.ros2.emulator``, its own process, as a robot's
controller manager is) on a ROS 2 domain of its own on this computer
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``), waits for its ``ready`` line, runs ``deploy-run
--backend ros2`` with the arguments after ``--``, stops the emulator (which prints what the robot
really did: its true violations), then runs ``deploy-run --backend sim`` with the same arguments
(lockstep) and prints goals and violations of both, and whether they agree within
``AGREEMENT`` (goals) / the larger of ``AGREEMENT`` and one tick (violations). ``make hil
ROBOT=arm3 BACKEND=ros2`` runs the shipped arm3 policy through it for 60 s::

    python -m sim2real.deploy.harness.ros2_hil --robot arm3 -- --policy policies/arm.onnx --duration 60

The exit code is the ros2 run's deploy-run's (0 clean, 1 hard violation, 2 fault, 3 bad input;
3 also when the emulator does not start), or 5 when the two runs disagree.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from pathlib import Path

from sim2real.deploy.harness.common import (
    deploy_run_command,
    hil_parser,
    parse_hil,
    run_beside,
    spawn_emulator,
)

#: Relative difference of goal success and violations within which the two runs agree (the
#: issue's acceptance: 10 %).
AGREEMENT = 0.10
EXIT_DISAGREE = 5


def ros_environment(domain_id: int) -> dict[str, str]:
    """This process's environment on ROS 2 domain ``domain_id``, discovery on this computer."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return env


def start_emulator(robot: str, mode: str, env: dict, extra=()) -> tuple[subprocess.Popen, str]:
    """The emulator in its own process and its ready line ('' if it exits or stays silent for
    :data:`sim2real.deploy.harness.common.START_TIMEOUT` s). Stop it with
    :func:`sim2real.deploy.harness.common.stop_emulator` (SIGTERM; it prints its counters on stderr)."""
    args = ["--robot", robot, "--mode", mode, *extra]
    proc, ready = spawn_emulator(
        "sim2real.deploy.ros2.emulator", args, stderr=subprocess.PIPE, env=env
    )
    return proc, ready or ""


def emulator_counters(stderr: str) -> dict | None:
    """The emulator's counters from its stderr (the ``emulator counters: {...}`` line)."""
    for line in reversed(stderr.splitlines()):
        if line.startswith("emulator counters: "):
            return json.loads(line.removeprefix("emulator counters: "))
    return None


def policy_mode(policy: str, robot: str) -> str:
    """The control mode of the ONNX ``policy`` for ``robot``."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.robots import load_robot

    return OnnxPolicy(policy, load_robot(robot)).spec.action.mode


def main(argv: list[str] | None = None) -> int:
    """Run the emulator, deploy-run against it, then on the plant; see the module docstring."""
    p = hil_parser(
        "ros2_hil",
        "deploy-run --backend ros2 against the ros2_control emulator, then --backend sim; "
        "arguments after '--' go to both deploy-runs.",
        domain=(42, "ROS 2 domain"),
    )
    p.add_argument(
        "--silence",
        default=None,
        metavar="START:DURATION",
        help="the emulator's joint_states silent for a while (a stall)",
    )
    p.add_argument("--no-sim", action="store_true", help="skip the --backend sim comparison")
    p.add_argument(
        "--plant-motors",
        default=None,
        metavar="FILE",
        help="the emulator's plant motors file (the motors as they are, unknown to deploy-run)",
    )
    args, rest = parse_hil(p, argv)
    if "--policy" not in rest and "--excitation" not in rest:
        p.error("give deploy-run's --policy (or --excitation) after '--'")
    with tempfile.TemporaryDirectory(prefix="hil-ros2-") as tmp:
        return _run(args, rest, Path(tmp))


def _run(args, rest: list[str], tmp: Path) -> int:
    if "--policy" in rest:
        mode = policy_mode(rest[rest.index("--policy") + 1], args.robot)
    else:  # an excitation drives position targets
        mode = "position"
    env = ros_environment(args.domain_id)
    extra = ["--seed", str(args.seed)]
    if args.plant_motors:
        extra += ["--plant-motors", args.plant_motors]
    if args.silence:
        extra += ["--silence", args.silence]
    emulator, ready = start_emulator(args.robot, mode, env, extra)
    report = tmp / "ros2.json"
    run = deploy_run_command("ros2", "--robot", args.robot, *rest, "--report", str(report))
    code = run_beside(emulator, ready, f"ros2_control emulator {ready}", run, env=env)
    err = emulator.stderr.read() if emulator.stderr else ""
    if not ready:
        return code
    counters = emulator_counters(err)
    print(f"hil: emulator counters {json.dumps(counters)}", flush=True)
    if args.no_sim or not report.is_file() or counters is None:
        return code
    sim_report = tmp / "sim.json"
    sim = deploy_run_command("sim", "--robot", args.robot, *rest, "--report", str(sim_report))
    print(f"hil: the same run on the simulated plant: deploy-run {' '.join(sim[3:])}", flush=True)
    subprocess.call(sim, stdout=subprocess.DEVNULL)
    if not sim_report.is_file():
        return code
    agree = compare(json.loads(report.read_text()), counters, json.loads(sim_report.read_text()))
    return code if code or agree else EXIT_DISAGREE


def compare(ros2: dict, counters: dict, sim: dict) -> bool:
    """Print goals and true violations of the ros2 run (the emulator's truth) and the sim run;
    whether they agree (module docstring)."""
    v_ros2, v_sim = counters["violations"]["any"], sim["violations"]["any"]
    ticks = sim["duration_s"] * sim["control_rate_hz"]
    v_ok = abs(v_ros2 - v_sim) <= max(AGREEMENT * max(v_ros2, v_sim), 1)
    ok = v_ok
    line = f"hil: violations (true ticks) ros2 {v_ros2}, sim {v_sim} of {ticks:.0f}"
    if ros2["goals"] is not None and sim["goals"] is not None:
        g_ros2, g_sim = ros2["goals"]["success_rate"] or 0.0, sim["goals"]["success_rate"] or 0.0
        g_ok = abs(g_ros2 - g_sim) <= AGREEMENT * max(g_sim, 1e-9)
        ok &= g_ok
        line = (
            f"hil: goals ros2 {ros2['goals']['reached']}/{ros2['goals']['issued']} "
            f"({100 * g_ros2:.1f} %, estimated), sim {sim['goals']['reached']}/"
            f"{sim['goals']['issued']} ({100 * g_sim:.1f} %, true); " + line.removeprefix("hil: ")
        )
    print(line + ("; they agree" if ok else f"; they DISAGREE (beyond {AGREEMENT:.0%})"))
    bus = ros2.get("bus") or {}
    if bus:
        rd, wr = bus["read_us"], bus["write_us"]
        print(
            f"hil: ros2 read p50 {rd['p50_us']:.0f} p99 {rd['p99_us']:.0f} us, write p50 "
            f"{wr['p50_us']:.0f} p99 {wr['p99_us']:.0f} us; stale reads {bus['stale_reads']} "
            f"of {bus['reads']}; stops "
            f"{ {k: v for k, v in ros2['faults']['by_cause'].items() if v} or 'none' }",
            flush=True,
        )
    return ok


if __name__ == "__main__":
    raise SystemExit(main())
