"""Short soak sessions of the tests (:func:`short_session`), and a session killed with SIGKILL
right after its first checkpoint (the kill-and-resume tests of arms, recurrent policies and
legged robots share it)."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

from sim2real.eval.soak import checkpoint as ckpt
from sim2real.eval.soak.session import SessionConfig, session_dir

REPO = Path(__file__).resolve().parent.parent
#: The options of each robot's short test session: arm3 reaches for a goal every 2 s and is
#: checkpointed every 3 simulated seconds; go2 follows a command for 4 s at a time.
SHORT_SESSION = {
    "arm3": {
        "goal_period": 2.0,
        "checkpoint_minutes": 0.05,
        "curve_seconds": 2.0,
        "operator_reset": 1.0,
    },
    "go2": {"goal_period": 4.0, "curve_seconds": 6.0, "window_minutes": 0.25},
}


def short_session(robot: str, policy, hours: float, **options) -> SessionConfig:
    """The :class:`SessionConfig` of ``robot``'s short test session (:data:`SHORT_SESSION`)
    with ``policy`` (a path) for ``hours`` h; ``options`` add to or override the table's."""
    return SessionConfig(
        robot=robot, policy=str(policy), hours=hours, **{**SHORT_SESSION[robot], **options}
    )


def kill_after_first_checkpoint(config, out: Path, timeout: float = 120.0) -> None:
    """Run ``config``'s session (``run_campaign`` with one worker, into ``out``) in a
    subprocess, and SIGKILL its process group as soon as the session's first checkpoint exists.

    Raises:
        AssertionError: the session ended before its first checkpoint, or wrote none within
            ``timeout`` s.
    """
    out = Path(out)
    cfg_file = out.parent / f"{out.name}.config.pkl"
    cfg_file.write_bytes(pickle.dumps(config))
    # no torch: an ONNX policy's session never imports it (importing it cost 1.7 CPU-s per
    # kill); one OpenMP thread should anything import it
    script = (
        "import pickle, sys\n"
        "from sim2real.eval.soak.campaign import run_campaign\n"
        "run_campaign(pickle.load(open(sys.argv[1], 'rb')), 1, sys.argv[2], progress=False)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script, str(cfg_file), str(out)],
        cwd=REPO,
        env=dict(os.environ, ORT_DISABLE_TELEMETRY="1", OMP_NUM_THREADS="1"),
        start_new_session=True,
    )
    manifest = session_dir(out, config.seed) / ckpt.MANIFEST
    deadline = time.monotonic() + timeout
    try:
        while not manifest.exists():
            assert proc.poll() is None, "the session ended before its first checkpoint"
            assert time.monotonic() < deadline, f"no checkpoint within {timeout} s"
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
