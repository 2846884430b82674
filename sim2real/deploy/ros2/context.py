"""An rclpy node spinning on a thread of its own, in a context of its own.

:class:`NodeThread` owns an rclpy ``Context`` (so that several nodes, a test's and the runtime's,
live in one process without sharing ``rclpy.init``), one node in it and a single-threaded
executor that a daemon thread spins. Every callback of the node (subscriptions, services, timers,
guard conditions) runs on that thread, one at a time; the control thread never spins it.

Where the node talks: ``ROS_DOMAIN_ID`` (default 0) and ``ROS_AUTOMATIC_DISCOVERY_RANGE``
(``LOCALHOST`` keeps it on this computer) of the environment, as every ROS 2 node reads them.
"""

from __future__ import annotations

import threading

from sim2real.deploy.ros2 import available
from sim2real.robots.errors import Sim2RealError

#: s the executor waits per spin before it looks at its stop flag (our choice).
SPIN_TIMEOUT = 0.1


class Ros2UnavailableError(Sim2RealError, ValueError):
    """rclpy or a message package does not import (the extra ``ros2`` is not installed): bad
    input for a command line that asked for ROS 2 (``deploy-run`` exits 3)."""


def require_ros2() -> None:
    """Raises :class:`Ros2UnavailableError` (saying how to install it) when ROS 2 is missing."""
    why = available()
    if why is not None:
        raise Ros2UnavailableError(why)


class NodeThread:
    """An rclpy node in its own context, spun by a single-threaded executor on a daemon thread.

    Args:
        name: The node's name. namespace: Its namespace ('' : the root).

    Attributes:
        context: The ``rclpy.Context``. node: The ``rclpy.node.Node`` (create its publishers,
            subscriptions and services before :meth:`start`, or from its own callbacks).

    Raises:
        Ros2UnavailableError: rclpy is not installed.
    """

    def __init__(self, name: str, namespace: str = ""):
        require_ros2()
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, namespace=namespace, context=self.context)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Spin the node on its thread (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._spin, name="ros2-node", daemon=True)
            self._thread.start()

    def spin_once(self, timeout: float) -> None:
        """Run at most one ready callback, waiting up to ``timeout`` s for one, on the calling
        thread: for a node whose owner spins it itself (never with :meth:`start`)."""
        self._executor.spin_once(timeout_sec=timeout)

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self._executor.spin_once(timeout_sec=SPIN_TIMEOUT)

    def close(self) -> None:
        """Stop spinning, destroy the node and shut the context down (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self.context.ok():
            self._executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
            self.context.try_shutdown()

    def __enter__(self) -> NodeThread:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
