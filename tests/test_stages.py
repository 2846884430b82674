"""The simulated plant and the runtime are composed of stage objects, each holding its own state, to which it
delegates by name (:class:`sim2real.deploy.backends.sim.plant.SimBackend`,
:class:`sim2real.deploy.runtime.loop.Runtime`, :func:`sim2real.deploy.core.delegate.delegate`): no mixin bases, the stages' arrays are the
plant's, a write through the plant reaches the stage."""

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.backend import BackendLifecycle
from sim2real.deploy.core.delegate import delegate, forward


def test_the_plant_is_its_stages_and_not_mixins(arm3):
    assert SimBackend.__mro__ == (SimBackend, BackendLifecycle, object)
    plant = SimBackend(arm3, envs=2)
    assert plant.noise_sigma is plant.joint_sensors.noise_sigma
    assert plant.effort_limit is plant.drives.effort_limit
    plant.dropout_probability[1] = 1.0  # a fault written through the plant is the sensors'
    assert plant.stale_context(1)["other_side"].startswith("every encoder reading lost")
    plant.grounds = [None, None]
    assert plant.truth.grounds == [None, None]
    assert np.array_equal(plant.true_position(), plant.truth.position())


def test_a_delegate_follows_a_replaced_stage_and_writes_only_when_writable():
    class Stage:
        def __init__(self, value):
            self.value = value

    class Owner:
        value = delegate("stage", "value")
        settable = delegate("stage", "value", writable=True)

    owner = Owner()
    owner.stage = Stage(1)
    assert owner.value == 1
    owner.stage = Stage(2)  # a new stage (a copy, a new model): followed
    assert owner.value == 2
    owner.settable = 3
    assert owner.stage.value == 3
    with pytest.raises(AttributeError):
        owner.value = 4


def test_a_delegate_forwards_data_and_a_method_is_forwarded(arm3):
    """``delegate`` is for data: one naming a method is refused where it is read; a method is
    ``forward``-ed, a method of the owner. Every delegate of the plant reads data (the
    runtime's: the next test)."""

    class Stage:
        def __init__(self):
            self.value = 1

        def double(self, x, times=2):
            return x * times

    class Owner:
        value = delegate("stage", "value")
        double = forward("stage", "double")
        wrong = delegate("stage", "double")

    owner = Owner()
    owner.stage = Stage()
    assert owner.value == 1 and owner.double(3) == 6 and owner.double(3, times=3) == 9
    with pytest.raises(TypeError, match=r"delegate\('stage', 'double'\) names a method"):
        owner.wrong  # noqa: B018
    plant = SimBackend(arm3, envs=1)
    delegates = [n for n, a in vars(SimBackend).items() if isinstance(a, property)]
    assert {"noise_sigma", "grounds", "free_base"} <= set(delegates)
    for name in delegates:
        getattr(plant, name)  # data, or a TypeError naming the method
    assert np.array_equal(plant.true_position(), plant.truth.position())


def test_the_runtime_is_its_stages_and_keeps_its_own_clock(arm3, tmp_path):
    """The runtime holds its run and its state dict as stages (no mixin bases); loading a state
    moves its tick and time, which only it writes."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime
    from tests.runtime_fixtures import adversarial_onnx

    assert Runtime.__mro__ == (Runtime, object)
    policy = OnnxPolicy(adversarial_onnx(tmp_path, arm3, "position"), arm3)
    rt = Runtime(arm3, policy, SimBackend(arm3, "position"))
    rt.start()
    rt.run(5)
    assert (rt.ticks, rt.gc_collections) == (5, rt.run_loop.gc_collections)
    assert rt.action is rt.supervision.action and rt.mode_names() == ["RUNNING"]
    state = rt.state_dict()
    rt.run(3)
    rt.load_state_dict(state)
    assert (rt.ticks, rt.time) == (5, state["time"])
