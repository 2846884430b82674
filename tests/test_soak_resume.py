"""A soak session resumed from its checkpoint is the run it would have been uninterrupted, tick
for tick, for a policy whose observation keeps state from one tick to the next: a frame history
(Isaac Lab's ``history_length``, filled with the first frame after a reset) and a gait clock that
stops while the robot stands. The stop replay's restore of a capture
(:class:`sim2real.eval.soak.counterfactual.StopReplay`) continues the same way."""

from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import onnx
import pytest
from onnx import helper, numpy_helper

from sim2real.eval.soak import checkpoint as ckpt
from sim2real.eval.soak.batch import SessionBatch
from sim2real.eval.soak.session import session_dir
from sim2real.eval.world.session_ranges import session_ranges
from tests.soak_fixtures import short_session

#: Ticks of the policy's frame history; the share of its oldest frame in what the go2 network reads.
HISTORY, OLDEST = 3, 0.05


def history_policy(source, path, stand_below: float = 0.1):
    """The go2 policy ``source`` reading a frame history: its graph takes ``HISTORY`` frames
    (oldest first, filled with the first frame after a reset) and feeds its network the newest
    plus ``OLDEST`` x (oldest - newest); its gait clock stops below ``stand_below`` m/s, rad/s."""
    model = onnx.load(str(source))
    spec = json.loads({p.key: p.value for p in model.metadata_props}["policy_spec"])
    graph = model.graph
    obs = graph.input[0]
    frame = obs.type.tensor_type.shape.dim[1].dim_value
    inner = f"{obs.name}_frame"
    for node in graph.node:
        node.input[:] = [inner if x == obs.name else x for x in node.input]
    obs.type.tensor_type.shape.dim[1].dim_value = frame * HISTORY
    constants = {
        "new_from": [frame * (HISTORY - 1)],
        "new_to": [frame * HISTORY],
        "old_from": [0],
        "old_to": [frame],
        "axis": [1],
    }
    for name, value in constants.items():
        graph.initializer.append(numpy_helper.from_array(np.array(value, np.int64), name))
    graph.initializer.append(numpy_helper.from_array(np.array(OLDEST, np.float32), "share"))
    head = [
        helper.make_node("Slice", [obs.name, "new_from", "new_to", "axis"], ["newest"]),
        helper.make_node("Slice", [obs.name, "old_from", "old_to", "axis"], ["oldest"]),
        helper.make_node("Sub", ["oldest", "newest"], ["gap"]),
        helper.make_node("Mul", ["gap", "share"], ["part"]),
        helper.make_node("Add", ["newest", "part"], [inner]),
    ]
    nodes = head + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    for block in spec["observation"]:
        if block["name"] == "gait_phase":
            block["stand_below"] = stand_below
    spec["history"] = {"length": HISTORY, "layout": "per_frame", "fill": "first"}
    del model.metadata_props[:]
    model.metadata_props.add(key="policy_spec", value=json.dumps(spec))
    onnx.save(model, str(path))
    return path


class Recorded(SessionBatch):
    """A batch that records, after every tick, the plant's true base state, joint angles and
    speeds and the runtime's last action of env 0."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.rows: list[np.ndarray] = []

    def on_tick(self, rt) -> None:
        super().on_tick(rt)
        b = self.backend
        self.rows.append(
            np.concatenate(
                [
                    b.true_base_state()[0],
                    b.true_position()[0],
                    b.true_velocity()[0],
                    rt.state.last_action[0],
                ]
            )
        )


@pytest.fixture(scope="module")
def config(go2_onnx, go2, tmp_path_factory):
    """4 s of go2 with the history policy, a checkpoint at 2 s."""
    policy = history_policy(go2_onnx, tmp_path_factory.mktemp("history") / "go2_history.onnx")
    return short_session(
        "go2", policy, 4.0 / 3600, checkpoint_minutes=2.0 / 60, ranges=session_ranges(go2, 10.0)
    )


def seeded(result: dict) -> dict:
    return {k: v for k, v in result.items() if k != "wall"}


def test_a_session_resumed_from_its_checkpoint_repeats_the_uninterrupted_run_tick_for_tick(
    config, tmp_path
):
    whole = Recorded([config], tmp_path / "whole", progress=False)
    assert whole.rt.spec.history is not None
    uninterrupted = whole.run()[0]
    half = whole.checkpoint_ticks
    arrays, meta = ckpt.read_checkpoint(session_dir(tmp_path / "whole", 0))
    assert meta["tick"] == half == whole.total_ticks // 2
    assert arrays["observation/ring/count"].tolist() == [HISTORY]
    assert np.isfinite(arrays["observation/clock_starts"]).sum() == 1  # the gait clock, running

    # the interrupted campaign's folder: its checkpoint at T/2, no result; resumed by a new batch
    crashed = session_dir(tmp_path / "crashed", 0)
    shutil.copytree(session_dir(tmp_path / "whole", 0), crashed)
    (crashed / "result.json").unlink()
    resumed = Recorded([config], tmp_path / "crashed", resume=True, progress=False)
    assert resumed.rt.ticks == half
    result = resumed.run()[0]

    np.testing.assert_array_equal(np.array(resumed.rows), np.array(whole.rows[half:]))
    assert seeded(result) == seeded(uninterrupted)


def test_the_stop_replays_restore_of_a_capture_repeats_the_session_tick_for_tick(config, tmp_path):
    batch = Recorded([config], tmp_path / "session", progress=False)
    start = 60
    batch.rt.run(start, on_tick=batch.on_tick)
    arrays, meta = batch.sessions[0].capture()
    meta = copy.deepcopy(meta)
    batch.rt.run(40, on_tick=batch.on_tick)

    twin = Recorded([config], tmp_path / "twin", progress=False, replay_stops=False)
    twin.restore(arrays, meta, "the capture")
    twin.rt.run(40, on_tick=twin.on_tick)
    np.testing.assert_array_equal(np.array(twin.rows), np.array(batch.rows[start:]))
