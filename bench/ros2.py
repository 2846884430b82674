"""The ``ros2`` item: what ``deploy-run --ros2`` costs the control loop.

The shipped Go2 policy (exported from ``sim2real/policies/go2.pt``, commanded 0.5 m/s forward) runs with
``deploy-run --realtime`` in this process for ``duration`` s, three times in one bench run:

- ``off``: no ROS 2;
- ``on``: ``--ros2`` (the node publishes ``joint_states``, ``imu`` and ``odom`` every tick and
  ``/diagnostics`` every second, :mod:`sim2real.deploy.ros2.bridge`), nobody listening;
- ``on+slow``: ``--ros2`` with a second process (:func:`_slow_operator`) that subscribes to every
  topic with callbacks that take ``SLOW_CALLBACK_S`` each and publishes ``cmd_vel`` at 10 Hz: a
  slow subscriber and a busy peer.

Reported per row: the tick's cost without physics (``tick_cost_us``, the runtime's own
histogram), the wake-up jitter, overruns and missed periods, the node's cost on the control
thread (``after_tick_us``: the copy into its buffer and the handing of ``cmd_vel``), the
messages published and the ticks the node did not publish (it fell behind and skipped them,
which never delays a tick). Every row talks on a ROS 2 domain of its own on this computer
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``). Without the extra ``ros2`` the item is skipped,
saying why.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from pathlib import Path

#: s each callback of the slow peer takes (our choice: longer than a 50 Hz period).
SLOW_CALLBACK_S = 0.03
#: The ROS 2 domain of the item (a domain no test of the suite uses: they take 100-199).
DOMAIN_ID = 77


def _slow_operator(domain: int, ready) -> None:  # pragma: no cover - runs in a child process
    """A second ROS 2 process: slow subscriptions to every topic of the node, ``cmd_vel`` at
    10 Hz (0.5 m/s forward)."""
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu, JointState

    rclpy.init()
    node = rclpy.create_node("slow_operator")

    def slow(_msg) -> None:
        time.sleep(SLOW_CALLBACK_S)

    for kind, topic in (
        (JointState, "/joint_states"),
        (Imu, "/imu"),
        (Odometry, "/odom"),
        (DiagnosticArray, "/diagnostics"),
    ):
        node.create_subscription(kind, topic, slow, 10)
    pub = node.create_publisher(Twist, "/cmd_vel", 10)

    def command() -> None:
        tw = Twist()
        tw.linear.x = 0.5
        pub.publish(tw)

    node.create_timer(0.1, command)
    ready.set()
    rclpy.spin(node)


def _row(name: str, report: dict) -> dict:
    from bench.session import deadline_figures

    node = report.get("ros2") or {}
    return {
        "config": name,
        **deadline_figures(report),
        "tick_cost_us": report["tick_cost_us"],
        "jitter_us": report["deadline"]["jitter_us"],
        "after_tick_us": node.get("after_tick_us"),
        "published": node.get("published"),
        "received": node.get("received"),
        "ticks_skipped": node.get("ticks_skipped"),
        "final_state": report["final_state"],
        "falls": (report.get("locomotion") or {}).get("falls"),
    }


def measure(folder: Path, duration: float) -> dict:
    """The ``ros2`` entry of results.json: ``{robot, duration_s, domain_id, rows: [...]}``, or
    ``{skipped: reason, rows: []}`` without rclpy (module docstring).

    Raises:
        RuntimeError: deploy-run refused its input or diverged (:func:`bench.session.
            _deploy_run`).
    """
    from sim2real.deploy.ros2 import available

    why = available()
    if why is not None:
        return {"skipped": why, "rows": []}
    from bench.busy import shipped_go2
    from bench.common import environment
    from bench.session import _deploy_run

    go2 = shipped_go2(folder)
    rows = []
    with environment(ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"):
        cmd = ("--command", "0.5,0,0")
        report, _, _ = _deploy_run(go2, duration, True, cmd)
        rows.append(_row("off", report))
        report, _, _ = _deploy_run(go2, duration, True, (*cmd, "--ros2"))
        rows.append(_row("on", report))
        ctx = multiprocessing.get_context("spawn")
        ready = ctx.Event()
        peer = ctx.Process(target=_slow_operator, args=(DOMAIN_ID, ready), daemon=True)
        peer.start()
        try:
            ready.wait(60)
            report, _, _ = _deploy_run(go2, duration, True, (*cmd, "--ros2"))
            rows.append(_row("on+slow", report))
        finally:
            peer.terminate()
            peer.join()
    return {"robot": "go2", "duration_s": float(duration), "domain_id": DOMAIN_ID, "rows": rows}
