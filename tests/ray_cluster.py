"""A local two-node Ray cluster whose worker node cannot see a folder of the driver's
(:func:`two_node_cluster`): the head (no CPU: no task runs there) and one worker node of one CPU
started in its own mount namespace (``unshare``) with an empty tmpfs mounted over the hidden
folder and its own working folder, so a task that opens a driver's path, absolute or relative,
finds nothing. Needs ``unshare`` (root, or unprivileged user namespaces) and Ray's ``ray``
command beside the interpreter."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RAY = Path(sys.executable).with_name("ray")


def unshare_command() -> list[str] | None:
    """The ``unshare`` prefix that gives a process its own mount namespace here, or None."""
    for cmd in (
        ["unshare", "--mount", "--propagation", "private"],
        ["unshare", "--user", "--map-root-user", "--mount"],
    ):
        try:
            done = subprocess.run([*cmd, "true"], capture_output=True, timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if done.returncode == 0:
            return cmd
    return None


def cluster_env() -> dict:
    """The environment of the nodes and of a driver: no token authentication (Ray >= 2.5x turns it
    on for a head when ``~/.ray/auth_token`` exists, and a driver connecting by address does not;
    the test cluster listens on the loopback only), no usage statistics."""
    return dict(
        os.environ, ORT_DISABLE_TELEMETRY="1", RAY_USAGE_STATS_ENABLED="0", RAY_AUTH_MODE="disabled"
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    """Stop a ``ray start --block`` we started: SIGTERM (it stops its node's processes), then
    SIGKILL to its process group."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            pass
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


@contextlib.contextmanager
def two_node_cluster(hidden: Path, logs: Path):
    """Yield the address of a two-node cluster whose worker node sees ``hidden`` empty.

    Args:
        hidden: A folder of the driver's (it must exist); the worker node sees an empty tmpfs
            there.
        logs: Folder for the nodes' output (``head.log``, ``worker.log``), the worker node's
            working folder and its ``TMPDIR``.
    """
    unshare = unshare_command()
    if unshare is None:
        raise RuntimeError("unshare cannot make a mount namespace here")
    logs.mkdir(parents=True, exist_ok=True)
    worker_cwd = logs / "worker-cwd"
    worker_cwd.mkdir(exist_ok=True)
    port = _free_port()
    address = f"127.0.0.1:{port}"
    temp = tempfile.mkdtemp(prefix="ray-", dir="/tmp")  # Ray's socket paths must stay short
    env = cluster_env()
    common = ["--node-ip-address", "127.0.0.1", "--block"]
    head = subprocess.Popen(
        [str(RAY), "start", "--head", "--port", str(port), "--num-cpus", "0",
         "--include-dashboard", "false", "--ray-client-server-port", str(_free_port()),
         "--dashboard-agent-listen-port", str(_free_port()), "--temp-dir", temp, *common],
        stdout=open(logs / "head.log", "wb"), stderr=subprocess.STDOUT, env=env,
        start_new_session=True,
    )  # fmt: skip
    worker = None
    try:
        deadline = time.monotonic() + 120
        while True:
            assert head.poll() is None, f"the head ended: {(logs / 'head.log').read_text()}"
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 1):
                break
            assert time.monotonic() < deadline, "the head did not start within 120 s"
            time.sleep(0.5)
        start = (
            f"mount -t tmpfs tmpfs {hidden} && exec {RAY} start --address {address} "
            f"--num-cpus 1 --dashboard-agent-listen-port {_free_port()} {' '.join(common)}"
        )
        worker_tmp = logs / "worker-tmp"  # a task killed with its driver leaves its folder there
        worker_tmp.mkdir(exist_ok=True)
        worker = subprocess.Popen(
            [*unshare, "sh", "-c", start],
            cwd=worker_cwd,
            stdout=open(logs / "worker.log", "wb"),
            stderr=subprocess.STDOUT,
            env=dict(env, TMPDIR=str(worker_tmp)),
            start_new_session=True,
        )
        yield address
    finally:
        if worker is not None:
            _stop(worker)
        _stop(head)
        shutil.rmtree(temp, ignore_errors=True)
