"""Real time on an ordinary computer: the wall clock's wait strategies (against a fake monotonic
clock: no timed assertions), and deploy-run's --wait/--spin, --cpu, --rt-priority, --lock-memory
and --require-rt (the settings read back from the report, the refused paths in a child process
whose CAP_SYS_NICE, CAP_IPC_LOCK and rlimits are dropped)."""

from __future__ import annotations

import ctypes
import ctypes.util
import io
import json
import os
import resource
import subprocess
import sys
import time

import pytest

from sim2real.deploy.cli.deploy_run import EXIT_BAD_INPUT, deploy_run_main
from sim2real.deploy.runtime.clock import SPIN_MARGIN_NS, WallClock
from tests.runtime_fixtures import adversarial_onnx

PERIOD = 0.002  # s: arm6's control period
PERIOD_NS = 2_000_000
STEP_NS = 7_000  # the fake clock advances this much per reading


class FakeTime:
    """A monotonic clock that advances ``step`` ns per reading, and a sleep that advances it by
    the time asked (and records it)."""

    def __init__(self, step: int = STEP_NS):
        self.t = 1_000_000_000
        self.step = step
        self.sleeps: list[float] = []
        self.reads = 0

    def now_ns(self) -> int:
        self.t += self.step
        self.reads += 1
        return self.t

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.t += int(seconds * 1e9)

    def work(self, ns: int) -> None:
        """The tick's own cost."""
        self.t += ns


def clock_with(fake: FakeTime, wait: str) -> WallClock:
    return WallClock(PERIOD, wait=wait, now_ns=fake.now_ns, sleep=fake.sleep)


# ---------------------------------------------------------------- the wait strategies
def test_spin_wait_returns_at_each_deadline_and_never_sleeps():
    fake = FakeTime()
    clock = clock_with(fake, "spin")
    clock.start()
    t0 = fake.t
    for k in range(1, 6):
        fake.work(400_000)  # a 400 us tick
        assert clock.wait() == 0
        deadline = t0 + k * PERIOD_NS
        assert deadline <= fake.t < deadline + STEP_NS  # returned at the first reading past it
    assert fake.sleeps == []  # the whole period was busy-waited
    assert clock.overruns == 0 and clock.missed_periods == 0
    assert clock.jitter.summary()["samples"] == 5
    assert clock.jitter.summary()["max_us"] < STEP_NS / 1e3


def test_hybrid_wait_sleeps_until_the_margin_then_spins_to_the_deadline():
    fake = FakeTime()
    clock = clock_with(fake, "hybrid")
    clock.start()
    t0 = fake.t
    fake.work(400_000)
    assert clock.wait() == 0
    assert len(fake.sleeps) == 1
    # slept the period minus the tick minus the margin (less the fake clock's own readings)
    expected = (PERIOD_NS - 400_000 - SPIN_MARGIN_NS) / 1e9
    assert fake.sleeps[0] == pytest.approx(expected, abs=3 * STEP_NS / 1e9)
    assert t0 + PERIOD_NS <= fake.t < t0 + PERIOD_NS + STEP_NS
    assert fake.reads > SPIN_MARGIN_NS // STEP_NS  # the margin was spun, reading the clock


def test_sleep_wait_sleeps_the_whole_remainder_without_spinning():
    fake = FakeTime()
    clock = clock_with(fake, "sleep")
    clock.start()
    fake.work(400_000)
    reads = fake.reads
    assert clock.wait() == 0
    assert fake.sleeps[0] == pytest.approx((PERIOD_NS - 400_000) / 1e9, abs=3 * STEP_NS / 1e9)
    assert fake.reads - reads <= 4  # no busy-wait after the sleep


@pytest.mark.parametrize("wait", ["sleep", "hybrid", "spin"])
def test_an_overrun_skips_the_missed_periods_in_every_wait_mode(wait):
    fake = FakeTime()
    clock = clock_with(fake, wait)
    clock.start()
    t0 = fake.t
    fake.work(int(2.5 * PERIOD_NS))  # its deadline was t0 + P; t0 + 2P has passed too
    assert clock.wait() == 2  # its own period and the one skipped
    assert clock.overruns == 1 and clock.missed_periods == 1  # t0 + 2P skipped, not run late
    assert t0 + 3 * PERIOD_NS <= fake.t <= t0 + 3 * PERIOD_NS + STEP_NS  # the grid is kept
    fake.work(100_000)
    assert clock.wait() == 0
    assert t0 + 4 * PERIOD_NS <= fake.t <= t0 + 4 * PERIOD_NS + STEP_NS


def test_wall_clock_refuses_an_unknown_wait_mode_and_runtime_still_exports_it():
    import sim2real.deploy.runtime
    import sim2real.deploy.runtime.clock

    assert sim2real.deploy.runtime.WallClock is sim2real.deploy.runtime.clock.WallClock
    with pytest.raises(ValueError, match="expected one of sleep, hybrid, spin, got 'busy'"):
        WallClock(PERIOD, wait="busy")


@pytest.mark.parametrize("wait", ["spin", "sleep"])
def test_the_safe_stop_on_overruns_stays_in_every_wait_mode(tmp_path, arm3, wait):
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime

    policy = OnnxPolicy(adversarial_onnx(tmp_path, arm3, "velocity"), arm3)
    rt = Runtime(
        arm3,
        policy,
        SimBackend(arm3, mode="velocity"),
        clock=WallClock(arm3.control_period, wait=wait),
    )
    rt.start()
    fast = rt.policy

    class Slow:
        spec = fast.spec

        def __call__(self, obs):
            time.sleep(0.012)  # > 2 periods of 5 ms: every tick overruns
            return fast(obs)

    rt.policy = Slow()
    rt.run(80)  # 2 of 3 periods missed: past velocity mode's 25 % of a second in ~0.4 s
    assert rt.clock.overruns >= 15
    assert rt.cause_names()[0] == "overrun"


# ---------------------------------------------------------------- deploy-run options
def run_cli(capsys, *argv):
    code = deploy_run_main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_a_cpu_this_process_cannot_use_exits_3_naming_it(capsys, tmp_path):
    allowed = ",".join(str(c) for c in sorted(os.sched_getaffinity(0)))
    code, _, err = run_cli(
        capsys, "--policy", str(tmp_path / "never_loaded.onnx"), "--realtime", "--cpu", "999"
    )
    assert code == EXIT_BAD_INPUT
    assert f"--cpu 999: no CPU 999 for this process; expected some of {allowed}" in err
    code, _, err = run_cli(capsys, "--policy", "x.onnx", "--realtime", "--cpu", "one")
    assert code == EXIT_BAD_INPUT and "expected N or N,M" in err


def test_wait_options_need_the_wall_clock_and_must_agree(capsys):
    code, _, err = run_cli(capsys, "--policy", "x.onnx", "--spin")
    assert code == EXIT_BAD_INPUT and "--spin needs the wall clock: add --realtime" in err
    code, _, err = run_cli(capsys, "--policy", "x.onnx", "--rt-priority", "10")
    assert code == EXIT_BAD_INPUT and "--rt-priority needs the wall clock" in err
    code, _, err = run_cli(capsys, "--policy", "x.onnx", "--realtime", "--spin", "--wait", "sleep")
    assert code == EXIT_BAD_INPUT and "--spin and --wait sleep disagree" in err
    code, _, err = run_cli(capsys, "--policy", "x.onnx", "--realtime", "--rt-priority", "100")
    assert code == EXIT_BAD_INPUT and "--rt-priority 100: expected an integer in 1..99" in err


def test_spin_and_affinity_are_applied_for_the_run_and_restored(capsys, tmp_path, arm3):
    policy = adversarial_onnx(tmp_path, arm3, "velocity")
    before = os.sched_getaffinity(0)
    cpu = max(before)
    report = tmp_path / "run.json"
    code, out, _ = run_cli(
        capsys,
        *("--policy", str(policy), "--duration", "0.1", "--report", str(report)),
        *("--realtime", "--spin", "--cpu", str(cpu), "--no-lock-memory"),
    )
    assert code != EXIT_BAD_INPUT  # 0, or 2 if a loaded machine overran the loop
    r = json.loads(report.read_text())
    assert r["deadline"]["wait"] == "spin"
    rts = r["realtime_settings"]
    assert rts["cpus"] == [cpu]  # read back with os.sched_getaffinity during the run
    requested = {"priority": None, "cpus": [cpu], "lock_memory": False, "require": False}
    requested["spin"] = True
    assert rts["requested"] == requested
    assert rts["scheduler"] == "SCHED_OTHER" and rts["memory_locked"] is False
    assert f"wait spin, SCHED_OTHER, CPUs {cpu}, memory not locked" in out
    assert os.sched_getaffinity(0) == before  # given back after the run


# ---------------------------------------------------------------- refused settings
PR_CAPBSET_DROP, CAP_IPC_LOCK, CAP_SYS_NICE = 24, 14, 23


def _unprivileged():
    """preexec_fn: no real-time priority and no memory lock for the child, root or not (the
    rlimits for a user; the capabilities dropped from the bounding set, so that the exec'd
    program does not get them, for root)."""
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
    resource.setrlimit(resource.RLIMIT_MEMLOCK, (0, 0))
    if os.geteuid() == 0:
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        for cap in (CAP_SYS_NICE, CAP_IPC_LOCK):
            libc.prctl(PR_CAPBSET_DROP, cap, 0, 0, 0)


def run_unprivileged(*argv, timeout=300):
    env = dict(os.environ, ORT_DISABLE_TELEMETRY="1")
    return subprocess.run(
        [sys.executable, *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        preexec_fn=_unprivileged,
    )


@pytest.fixture(scope="module")
def refused_here():
    """Skip where even the dropped child may use SCHED_FIFO (a process without CAP_SETPCAP
    keeps its CAP_SYS_NICE)."""
    probe = run_unprivileged(
        "-c", "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))", timeout=60
    )
    if probe.returncode == 0:
        pytest.skip("cannot take CAP_SYS_NICE away from a child process here")


def test_a_refused_priority_and_memory_lock_say_so_and_the_run_continues(
    refused_here, tmp_path, arm3
):
    policy = adversarial_onnx(tmp_path, arm3, "velocity")
    report = tmp_path / "run.json"
    done = run_unprivileged(
        *("-m", "sim2real.deploy.cli.deploy_run", "--policy", str(policy), "--duration", "0.1"),
        *("--realtime", "--rt-priority", "10", "--report", str(report)),
    )
    assert done.returncode in (0, 2), done.stderr  # ran (2: a loaded machine overran it)
    notes = [line for line in done.stderr.splitlines() if "note:" in line]
    assert len(notes) == 2, done.stderr  # one line each
    fifo = next(n for n in notes if "SCHED_FIFO" in n)
    assert "SCHED_FIFO priority 10 refused (Operation not permitted)" in fifo
    assert "running at normal priority" in fifo and "CAP_SYS_NICE" in fifo
    assert "ulimit -r 10" in fifo and "rtprio 10" in fifo
    mlock = next(n for n in notes if "memory lock" in n)  # on by default with --rt-priority
    assert "memory lock refused" in mlock and "CAP_IPC_LOCK" in mlock
    rts = json.loads(report.read_text())["realtime_settings"]
    assert rts["scheduler"] == "SCHED_OTHER" and rts["memory_locked"] is False
    assert rts["notes"] == notes


def test_require_rt_makes_a_refused_priority_exit_3(refused_here, tmp_path, arm3):
    policy = adversarial_onnx(tmp_path, arm3, "velocity")
    done = run_unprivileged(
        *("-m", "sim2real.deploy.cli.deploy_run", "--policy", str(policy), "--duration", "0.1"),
        *("--realtime", "--rt-priority", "10", "--no-lock-memory", "--require-rt"),
    )
    assert done.returncode == EXIT_BAD_INPUT
    assert "SCHED_FIFO priority 10 refused" in done.stderr
    assert "deploy-run: error: --require-rt: SCHED_FIFO priority refused" in done.stderr


# ---------------------------------------------------------------- nothing compiles in a tick
NO_COMPILE_IN_TICKS = r"""
import pathlib, sys, tempfile
from numba.core import dispatcher
from sim2real.robots import load_robot
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Runtime
from tests.runtime_fixtures import adversarial_onnx

compiled = []
original = dispatcher.Dispatcher._compile_for_args
for name, mode in (("arm3", "position"), ("arm3", "velocity"), ("arm3", "torque"), ("go2", "position")):
    robot = load_robot(name)
    path = adversarial_onnx(pathlib.Path(tempfile.mkdtemp()), robot, mode)
    rt = Runtime(robot, OnnxPolicy(path, robot), SimBackend(robot, mode=mode))
    rt.start()

    def spy(self, *args, _where=f"{name} {mode}", **kwargs):
        compiled.append(f"{_where}: {self.py_func.__module__}.{self.py_func.__qualname__}")
        return original(self, *args, **kwargs)

    dispatcher.Dispatcher._compile_for_args = spy
    rt.run(300)
    dispatcher.Dispatcher._compile_for_args = original
print("\n".join(compiled))
"""


def test_no_kernel_compiles_or_loads_in_a_tick():
    """Every compiled kernel a tick calls is compiled (or loaded from numba's cache) when its
    stage is built, for the argument types the tick passes: a first call in a tick costs 3-10 ms
    (a wall-clock overrun of a 500 Hz loop). A fresh interpreter, arm3 in every control mode and
    go2: no numba dispatcher compiles a specialization in 300 ticks after ``start``."""
    out = subprocess.run(
        [sys.executable, "-c", NO_COMPILE_IN_TICKS],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip() == "", out.stdout


def test_the_priority_reaches_the_threads_the_process_already_has():
    """A robot's I/O threads (a DDS library's receive threads, a command re-send thread) start
    before the loop; at SCHED_FIFO the loop would wait on them at normal priority. Each is put at
    the loop's priority for the run and given its old setting back after."""
    import threading

    from sim2real.deploy.harness.common import fifo_refused
    from sim2real.deploy.runtime.realtime import RealtimeRequest, RealtimeSettings

    if fifo_refused(10):
        pytest.skip("SCHED_FIFO is not permitted here")
    started, done = threading.Event(), threading.Event()
    tid = []

    def io_thread():
        tid.append(threading.get_native_id())
        started.set()
        done.wait(30)

    t = threading.Thread(target=io_thread, daemon=True)
    t.start()
    started.wait(30)
    try:
        with RealtimeSettings(RealtimeRequest(priority=10), stream=io.StringIO()) as s:
            assert os.sched_getscheduler(tid[0]) == os.SCHED_FIFO
            assert os.sched_getparam(tid[0]).sched_priority == 10
            assert s.summary()["other_threads_raised"] >= 1
        assert os.sched_getscheduler(tid[0]) == os.SCHED_OTHER
        assert os.sched_getscheduler(0) == os.SCHED_OTHER
    finally:
        done.set()
        t.join()
