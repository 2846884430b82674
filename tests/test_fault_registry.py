"""The soak's fault kinds are registries, not chains on their names: a kind is registered with
what it does (the injector's room, :mod:`sim2real.deploy.backends.sim.fault_kinds`) and how the
soak draws it (the schedule's room, :mod:`sim2real.eval.world.fault_draws`); a kind registered in
one room and not the other is named, and a kind made up here is parsed, drawn and injected with
no other file edited."""

import numpy as np
import pytest

from sim2real.deploy.backends.sim.fault_kinds import FAULT_KINDS, FaultKind, register_fault_kind
from sim2real.deploy.backends.sim.faults import KINDS, Fault, FaultInjector
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.eval.soak.falls import push_kinds
from sim2real.eval.world.fault_draws import FAULT_DRAWS, FaultDraw, register_fault_draw
from sim2real.eval.world.fault_schedule import FaultRanges
from sim2real.eval.world.ranges_file import load_ranges_text
from sim2real.eval.world.session_draw import sample_session

#: rad, what the made-up fault adds to every encoder reading.
OFFSET = 0.25


def missing_parts() -> list[str]:
    """``"<kind>: <part>"`` for a fault kind the injector applies and the soak cannot draw, or
    one the soak draws and no injector applies."""
    kinds, draws = set(FAULT_KINDS.names()), set(FAULT_DRAWS.names())
    return [f"{k}: draw" for k in sorted(kinds - draws)] + [
        f"{k}: injector kind" for k in sorted(draws - kinds)
    ]


@pytest.fixture
def scoped():
    """What a test registers is forgotten after it."""
    with FAULT_KINDS.scoped(), FAULT_DRAWS.scoped():
        yield


def _offset(injector, fault, envs, frame):
    """The made-up kind's frame hook: every encoder reading ``OFFSET`` rad off."""
    frame.position[envs] += OFFSET


def _register_offset(draw: bool = True) -> None:
    register_fault_kind(FaultKind("encoder-offset", "encoders read OFFSET rad off", frame=_offset))
    if draw:
        register_fault_draw(
            FaultDraw("encoder-offset", lambda c, rng: (float(rng.uniform(0.5, 1.0)), None))
        )


def test_every_fault_kind_has_a_draw_and_a_missing_one_is_named(scoped):
    assert KINDS == ("dropout", "stale", "nan-action", "latency", "push", "cable")
    assert missing_parts() == [], "fault kinds without a draw:\n" + "\n".join(missing_parts())
    assert FaultRanges().kinds == KINDS  # every soak's default: the built-in kinds, in order
    assert push_kinds() == ("push", "cable")
    _register_offset(draw=False)
    assert missing_parts() == ["encoder-offset: draw"]
    with pytest.raises(ValueError, match="FaultRanges.kinds: 'encoder-offset' is unknown"):
        FaultRanges(kinds=("encoder-offset",))
    with pytest.raises(ValueError, match="fault kind 'hum': expected a plant, frame or action"):
        register_fault_kind(FaultKind("hum", "does nothing"))
    with pytest.raises(ValueError, match="fault kind 'push' is registered already"):
        register_fault_kind(FaultKind("push", "again", action=_offset))


def test_a_made_up_fault_kind_is_parsed_drawn_and_injected(scoped, arm3):
    with pytest.raises(ValueError, match="KIND one of"):
        Fault.parse("encoder-offset@1:0.5")
    _register_offset()
    assert missing_parts() == []
    assert "encoder-offset" not in FaultRanges().kinds  # not in every soak's draw unless asked
    # deploy-run's --inject form
    assert Fault.parse("encoder-offset@1:0.5") == Fault("encoder-offset", 1.0, 0.5)
    with pytest.raises(ValueError, match="encoder-offset takes no MAGNITUDE"):
        Fault.parse("encoder-offset=2@1:0.5")
    # a ranges file names it: the session's schedule draws it, by its own draw
    text = "[faults]\nkinds = ['encoder-offset']\nmean_interval = 5.0\n"
    ranges = load_ranges_text(text, "offset.toml", arm3)
    draw = sample_session(arm3, 4, 120.0, ranges)
    assert draw.faults and {f.kind for f in draw.faults} == {"encoder-offset"}
    assert all(0.5 <= f.duration <= 1.0 for f in draw.faults)
    assert sample_session(arm3, 4, 120.0, ranges).faults == draw.faults  # seeded
    # the injector applies its hook while it is in force, on its env only
    backend = SimBackend(arm3, envs=2)
    fault = Fault("encoder-offset", 1.0, 0.5, envs=(1,))
    injector = FaultInjector([fault], backend)
    frame = backend.read()
    before = frame.position.copy()
    injector.before_read(1.2)
    injector.filter_frame(1.2, frame)
    np.testing.assert_allclose(frame.position[1], before[1] + OFFSET)
    np.testing.assert_array_equal(frame.position[0], before[0])
    assert injector.log[0]["kind"] == "encoder-offset"
    frame = backend.read()
    before = frame.position.copy()
    injector.filter_frame(2.0, frame)  # over: the readings as read
    np.testing.assert_array_equal(frame.position, before)
