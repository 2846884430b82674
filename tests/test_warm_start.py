"""A run pays its compilations before its first deadline, never in a tick.

Each case runs deploy-run in a fresh interpreter (numba's in-memory specializations empty, its
disk cache as a user's) with numba's ``Dispatcher.compile`` wrapped to note every
specialization asked for once the runtime's first tick has begun: a kernel bound lazily on its
first use (the guard's motion envelope was: 0.6 s in a fresh clone's first period, 10-25 ms
with the cache warm, reported as ``longest overruns ... in smooth``) shows up there. The
assertion is on what was compiled, not on how long anything took.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.runtime_fixtures import zero_action_onnx

#: Run in the fresh interpreter: deploy-run's own main with the compile probe around it.
PROBE = """
import json, sys
from numba.core import dispatcher
from sim2real.deploy.runtime import loop

late, ticking = [], [False]
compile_ = dispatcher.Dispatcher.compile
def compile(self, sig):
    if ticking[0] and tuple(sig) not in self.overloads:
        late.append(f"{self.py_func.__module__}.{self.py_func.__name__}")
    return compile_(self, sig)
dispatcher.Dispatcher.compile = compile
tick_ = loop.Runtime.tick
def tick(self):
    ticking[0] = True
    return tick_(self)
loop.Runtime.tick = tick
from sim2real.deploy.cli.deploy_run import deploy_run_main
code = deploy_run_main(sys.argv[1:])
print("LATE " + json.dumps(late))
sys.exit(code)
"""


@pytest.mark.parametrize(
    "robot, extra",
    [
        ("arm3", ()),  # velocity mode: the motion envelope's certifier
        # the wall clock's path; --overrun-limit 1: no overrun rate trips a safe stop (the check
        # is "missed fraction > limit"), so a busy machine's overruns do not end the run early
        # (it FAULTED at 0.5 beside 15 other processes) and every tick is still probed
        ("arm3", ("--realtime", "--overrun-limit", "1")),
        ("so101", ()),  # position mode
        ("go2", ("--command", "0.5,0,0")),  # a floating base: the base estimator, the fall check
        ("so101", ("--excitation", "default")),  # make sysid's recording: no ONNX policy
    ],
    ids=["arm3", "arm3-realtime", "so101", "go2", "so101-excitation"],
)
def test_no_kernel_is_compiled_after_the_first_tick_begins(tmp_path, request, robot, extra):
    argv = ["--backend", "sim", "--robot", robot, "--duration", "1"]
    if "--excitation" not in extra:
        policy = zero_action_onnx(request.getfixturevalue(robot), tmp_path / f"{robot}.onnx")
        argv += ["--policy", str(policy)]
    done = subprocess.run(
        [sys.executable, "-c", PROBE, *argv, *extra],
        capture_output=True,
        text=True,
        timeout=300,
    )
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    late = json.loads(out.split("LATE ", 1)[1].splitlines()[0])
    assert late == [], f"compiled inside the loop: {late}"
    # the summary's longest overruns are the clock's overruns: none without one
    if "overruns 0," in out:
        assert "longest overruns" not in out, out


def test_a_lockstep_run_has_no_overrun_however_long_a_tick(arm3):
    """Simulated time keeps no deadline: a tick longer than its period is no overrun (the
    clock counts none), in the long-tick rows either; on a wall clock it is one."""
    from sim2real.deploy.observe.long_ticks import HEAD, TICK, TOTAL, LongTicks
    from sim2real.deploy.runtime.loop import STAGES

    ticks = LongTicks(STAGES)
    ticks.table[0, TICK], ticks.table[0, TOTAL] = 1, 10 * round(arm3.control_period * 1e9)
    ticks.table[0, HEAD] = ticks.table[0, TOTAL]
    assert [r["overran"] for r in ticks.rows(arm3.control_period, deadline=False)] == [False]
    assert [r["overran"] for r in ticks.rows(arm3.control_period)] == [True]
