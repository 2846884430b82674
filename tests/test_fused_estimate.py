"""The fused estimate and observe stages (:meth:`CompiledSupervision.estimate_observe`, one
compiled call over a table of addresses) give the separate stages' results bit for bit, and so
does the action screen over its table (:meth:`CompiledSupervision.screen`).

Two runtimes run the same scripted ticks of ``tests/test_compiled_tick.py`` (seeded plants with
dropouts, the fault injector's faults, a hot winding, a drive error, overruns, NaN actions, the
operator's resets): one the tick as it is, one whose estimate stage is the fused call
(:class:`FusedRuntime`). A covariance written NaN in the middle makes the estimator re-initialize
a joint (the call's ``RECOVER`` path). The screen's table is built over the policy's output
buffer, when the policy returns the same array twice in a row: a policy that does (its
:class:`SameBuffer`) is compared with one whose runtime never builds the table. Tolerance: none.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.runtime import Runtime
from tests.runtime_fixtures import adversarial_onnx
from tests.test_compiled_tick import build

TICKS = 900
#: The tick at which env 0's first joint's covariance is written NaN (in both runtimes).
CORRUPT = 240


class FusedRuntime(Runtime):
    """The tick with its estimate and observe stages in one call: the estimator's update and
    the kinematics only note the frame, the supervision runs the fused call, the observation
    returns its result."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._frame = None
        self.fused_calls = 0

        def note(frame, state, acceleration=None):
            self._frame = frame
            return state

        self.estimator.update = note
        self.kinematics.update = lambda state: state

    def _supervise(self, state, drive_errors):
        self._compiled.estimate_observe(
            self._frame, drive_errors, self._input, self.spec, self.goal, self._obs
        )
        self.fused_calls += 1

    def _observe(self, state):
        return self._obs


def run(rt: Runtime, ticks: int) -> dict[str, np.ndarray]:
    envs, n = rt.envs, rt.n
    out = {
        "obs": np.zeros((ticks, envs, rt.spec.obs_dim), dtype=np.float32),
        "q": np.zeros((ticks, envs, n)),
        "dq": np.zeros((ticks, envs, n)),
        "ee": np.zeros((ticks, envs, 12)),
        "command": np.zeros((ticks, envs, n)),
        "mode": np.zeros((ticks, envs), dtype=np.int8),
        "cause": np.zeros((ticks, envs), dtype=np.int8),
        "effort_scale": np.zeros((ticks, envs, n)),
    }
    faulted_since = np.full(envs, -1)
    for k in range(ticks):
        if k == CORRUPT:
            rt.estimator.covariance[0, 0, 0, 0] = np.nan
        rt.tick()
        out["obs"][k] = rt._obs
        out["q"][k], out["dq"][k] = rt.state.q, rt.state.dq
        out["ee"][k] = np.concatenate(
            [rt.state.ee_position, rt.state.ee_rotation.reshape(envs, 9)], axis=1
        )
        out["command"][k] = rt.command
        out["mode"][k], out["cause"][k] = rt.mode, rt.cause
        out["effort_scale"][k] = rt.guard.effort_scale
        faulted = rt.mode == 4  # Mode.FAULTED
        faulted_since[~faulted] = -1
        faulted_since[faulted & (faulted_since < 0)] = k
        reset = faulted & (k - faulted_since >= 2)
        if reset.any():
            rt.reset_faults(reset)
    return out


@pytest.mark.parametrize("robot_name", ["arm3", "arm6"])
@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_the_fused_call_equals_the_separate_stages(tmp_path, request, robot_name, mode):
    robot = request.getfixturevalue(robot_name)
    path = adversarial_onnx(tmp_path, robot, mode, nan_probability=0.02)
    separate = build(robot, mode, path, Runtime)
    fused = build(robot, mode, path, FusedRuntime)
    a, b = run(separate, TICKS), run(fused, TICKS)
    assert fused._compiled._fused and fused.fused_calls == TICKS
    for key in a:
        for k in range(TICKS):  # the first tick that differs, named
            if not np.array_equal(a[key][k], b[key][k], equal_nan=True):
                np.testing.assert_array_equal(a[key][k], b[key][k], err_msg=f"{key}, tick {k}")
    sa, sb = separate.state_dict(), fused.state_dict()
    assert sa.keys() == sb.keys()
    for key in sa:
        if not key.startswith(("latency/", "tick_cost/", "clock/jitter/")):
            np.testing.assert_array_equal(sa[key], sb[key], err_msg=key)
    assert fused.estimator.reinitializations[0] > 0  # the RECOVER path ran
    assert (a["mode"] == 3).any()  # safe stops: the supervision's Python part ran


class SameBuffer:
    """A policy that returns its output in one buffer (as ``OnnxPolicy`` does)."""

    def __init__(self, policy):
        self.policy, self.spec = policy, policy.spec
        self.out = np.zeros((2, policy.spec.act_dim), dtype=np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self.out[:] = self.policy(obs)
        return self.out


@pytest.mark.parametrize("robot_name", ["arm3", "arm6"])
@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_the_screen_over_its_table_equals_the_kernel_call(tmp_path, request, robot_name, mode):
    robot = request.getfixturevalue(robot_name)
    path = adversarial_onnx(tmp_path, robot, mode, nan_probability=0.02)
    tabled, plain = build(robot, mode, path, Runtime), build(robot, mode, path, Runtime)
    for rt in (tabled, plain):
        rt.policy = SameBuffer(rt.policy)
    plain._compiled._bind_screen = lambda action: None
    a, b = run(tabled, TICKS), run(plain, TICKS)
    assert tabled._compiled._screen_action is tabled.policy.out
    assert plain._compiled._screen_action is None
    for key in a:
        for k in range(TICKS):
            if not np.array_equal(a[key][k], b[key][k], equal_nan=True):
                np.testing.assert_array_equal(a[key][k], b[key][k], err_msg=f"{key}, tick {k}")
    np.testing.assert_array_equal(tabled.action, plain.action)
    np.testing.assert_array_equal(tabled.target, plain.target)
    assert int(tabled.counters.non_finite_actions.sum()) > 0
