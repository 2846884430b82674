"""The fused estimate and observe stages (:meth:`CompiledSupervision.estimate_observe`, one
compiled call over one packed table) give the separate stages' results bit for bit, and so
does the action screen over its table (:meth:`CompiledSupervision.screen`).

Two runtimes run the same scripted ticks of ``tests/test_compiled_tick.py`` (seeded plants with
dropouts, the fault injector's faults, a hot winding, a drive error, overruns, NaN actions, the
operator's resets): one the tick as it is (a fixed base: the fused call), one whose estimate and observe stages are
the separate calls (:class:`SeparateRuntime`). A covariance written NaN in the middle makes the estimator re-initialize
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


class SeparateRuntime(Runtime):
    """The tick with its estimate and observe stages as separate calls (the estimator, the
    kinematics, the supervision, the observation), as a floating base runs them."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._fused = False


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
    separate = build(robot, mode, path, SeparateRuntime)
    fused = build(robot, mode, path, Runtime)
    a, b = run(separate, TICKS), run(fused, TICKS)
    assert fused._fused and fused._compiled._fused  # the tick ran the one call over its table
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
