"""The other stacks are one module each (:mod:`sim2real.stacks`, the record and registry in
:mod:`sim2real.deploy.core.stacks`): every registered stack has every face or says why not, and
each face lives no higher than the room that asks for it. A ninth stack, one module outside the
tree registered through a package entry point, is recognised, read and inspected through the
normal paths (``OnnxPolicy``, ``policy-export --inspect``, ``deploy-run --motion``'s clip reader)
with no other file edited."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from sim2real.deploy.core.registry import load_target
from sim2real.deploy.core.stacks import (
    FACES,
    STACK_REGISTRY,
    Absent,
    DomainReader,
    Stack,
    TrackingLoop,
    register_stack,
    stacks,
)

#: The room each face is asked from, and so the package an in-tree face must live in (the floors:
#: a dispatch site imports a face from its own room or below, never above it).
FACE_ROOMS = {
    "detect": "sim2real.deploy.spec.",
    "contract": "sim2real.deploy.spec.",
    "clips": "sim2real.deploy.tasks.",
    "domain": "sim2real.eval.world.",
    "terrain": "sim2real.eval.world.",
    "own_loop": "sim2real.stacks.loops.",
    "tracking_loop": "sim2real.stacks.loops.",
}


def face_problems(stack: Stack) -> list[str]:
    """``"<stack>: <face>: <what is wrong>"`` for each face of ``stack`` that neither resolves to
    what its dispatch site asks for nor is declared :class:`Absent` with a reason."""
    from sim2real.deploy.tasks.motion.formats import ClipFormat

    out = []
    for face in FACES:
        value = getattr(stack, face, None)
        where = f"{stack.name}: {face}"
        if isinstance(value, Absent):
            if not value.reason.strip():
                out.append(f"{where}: Absent without a reason")
            continue
        if value is None:
            out.append(f"{where}: missing (declare Absent(reason))")
            continue
        if isinstance(value, str):
            if value.startswith("sim2real.") and not value.startswith(FACE_ROOMS[face]):
                out.append(f"{where}: {value} lives above the room that asks ({FACE_ROOMS[face]})")
            try:
                value = load_target(value)
            except (ImportError, AttributeError) as exc:
                out.append(f"{where}: {getattr(stack, face)!r} does not resolve ({exc})")
                continue
        shape = {
            "detect": callable,
            "contract": callable,
            "own_loop": callable,
            "tracking_loop": lambda v: (
                isinstance(v, TrackingLoop) and callable(v.folder) and callable(v.play)
            ),
            "terrain": lambda v: isinstance(v, type),
            "domain": lambda v: isinstance(v, DomainReader),
            "clips": lambda v: bool(v) and all(isinstance(f, ClipFormat) for f in v),
        }[face]
        if not shape(value):
            out.append(f"{where}: {value!r} is not what the face is")
    if isinstance(stack.detect, Absent) != isinstance(stack.contract, Absent):
        out.append(f"{stack.name}: detect and contract: one without the other")
    return out


def test_every_registered_stack_has_every_face_or_says_why_not():
    names = [s.name for s in stacks()]
    assert {"rl_sar", "holosoma", "mjlab", "isaaclab", "unitree_deploy", "legged_gym"} <= set(names)
    assert {"beyondmimic", "robomimic"} <= set(names) and len(names) == len(set(names))
    problems = [p for s in stacks() for p in face_problems(s)]
    assert problems == [], "stacks with a face neither resolving nor Absent:\n" + "\n".join(
        problems
    )


def test_a_stack_lacking_a_face_is_named_with_the_face():
    with pytest.raises(ValueError, match=r"stack 'lacking': face 'terrain' = None: expected"):
        register_stack(_stack("lacking", terrain=None))
    broken = _stack("broken", own_loop="sim2real.stacks.loops.nowhere:run")
    assert face_problems(broken) == [
        "broken: own_loop: 'sim2real.stacks.loops.nowhere:run' does not resolve "
        "(No module named 'sim2real.stacks.loops.nowhere')"
    ]
    high = _stack("high", contract="sim2real.eval.world.domain:domain_toml")
    assert face_problems(high)[0].startswith("high: contract: sim2real.eval.world.domain:")


def test_holosoma_is_detected_once_by_its_stack():
    """The training domain asks the stack that recognises the file (no second test of holosoma's
    metadata in the domain's room)."""
    root = Path(__file__).resolve().parent.parent
    text = (root / "sim2real" / "eval" / "world" / "domain.py").read_text(encoding="utf-8")
    assert 'experiment_config" in' not in text and "detect_stack" in text


def _stack(name: str, **faces) -> Stack:
    given = {f: Absent("a test's") for f in FACES} | faces
    return Stack(name=name, about="a test's", rank=99, **given)


# ------------------------------------------------------------------------------ a ninth stack
NINTH = '''
"""ninthstack: a made-up training stack. Its ONNX export carries ``ninth_joints`` (comma-joined,
its order), ``ninth_kp``, ``ninth_kd``, ``ninth_default`` and ``ninth_rate`` metadata and reads
``base_ang_vel, projected_gravity, command, joint_pos, joint_vel, actions``; its clips are JSON
(``{"fps", "joints", "root", "q"}``)."""

import json
from pathlib import Path

import numpy as np

from sim2real.deploy.core.stacks import Absent, Stack, register_stack
from sim2real.deploy.spec.foreign.contract import Term
from sim2real.deploy.tasks.motion.clip import MotionClip
from sim2real.deploy.tasks.motion.formats import ClipFormat

TERMS = (
    ("base_ang_vel", "base_angular_velocity", 3),
    ("projected_gravity", "projected_gravity", 3),
    ("command", "velocity_command", 3),
    ("joint_pos", "joint_position", -1),
    ("joint_vel", "joint_velocity", -1),
    ("actions", "last_action", -1),
)


def detect(facts):
    return "ninth_joints" in facts.metadata


def read(facts):
    md, fail = facts.metadata, facts.failure("ninthstack")

    def floats(key):
        try:
            return tuple(float(x) for x in md[key].split(","))
        except (KeyError, ValueError):
            raise fail(f"metadata '{key}': expected comma-joined numbers") from None

    return facts.contract(
        "ninthstack", "ONNX metadata (ninthstack's exporter)",
        joint_names=tuple(md["ninth_joints"].split(",")),
        terms=[Term(n, kind, size, 1.0, None) for n, kind, size in TERMS],
        default_pose=floats("ninth_default"), action_scale=0.25,
        kp=floats("ninth_kp"), kd=floats("ninth_kd"), control_rate=floats("ninth_rate")[0],
        found=[(k, md[k]) for k in md],
    )


def read_clip(request):
    data = json.loads(Path(request.path).read_text())
    q = np.asarray(data["q"], float)
    root = np.asarray(data["root"], float)
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (len(q), 1))
    return MotionClip(Path(request.path), float(data["fps"]), tuple(data["joints"]), q,
                      np.gradient(q, axis=0) * data["fps"], root, quat)


STACK = register_stack(Stack(
    name="ninthstack", about="a made-up stack (a test's)", rank=1,
    detect=detect, contract=read,
    domain=Absent("ninthstack records no randomization"),
    clips=(ClipFormat("ninth_json", ".json", (), "ninthstack", read_clip),),
    terrain=Absent("it trains on a plane"), own_loop=Absent("no replica of its loop"),
    tracking_loop=Absent("no replica of its loop"),
))
'''


def _ninth_dist(folder: Path) -> Path:
    """``ninthstack``'s one module and the dist-info pip would write for it (its entry point in the
    group ``sim2real.stacks``), in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "ninth_stack.py").write_text(textwrap.dedent(NINTH))
    info = folder / "ninth_stack-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: ninth-stack\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[sim2real.stacks]\nninthstack = ninth_stack\n")
    return folder


def _ninth_policy(path: Path, go2) -> Path:
    """A ninthstack export for go2's joints in reversed order: obs (1, 45) -> actions (1, 12)."""
    order = list(reversed(go2.joint_names))
    index = [go2.joint_names.index(n) for n in order]
    weight = np.full((45, 12), 1e-3, np.float32)
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["obs", "w"], ["actions"])],
        "ninth",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, 45])],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, 12])],
        [helper.make_tensor("w", TensorProto.FLOAT, [45, 12], weight.ravel().tolist())],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    joined = ",".join

    def per_joint(values) -> str:
        return joined(f"{float(values[i]):g}" for i in index)

    metadata = {
        "ninth_joints": joined(order),
        "ninth_kp": per_joint(np.full(12, 30.0)),
        "ninth_kd": per_joint(np.full(12, 0.75)),
        "ninth_default": per_joint(go2.home),
        "ninth_rate": "50",
    }
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(model, str(path))
    return path


@pytest.fixture
def ninth(tmp_path, monkeypatch):
    """The ninth stack installed (on sys.path with its dist-info) and loaded by the registry's
    entry-point path; forgotten after the test."""
    with STACK_REGISTRY.scoped():  # the stacks before it, the entry points there then loaded
        monkeypatch.syspath_prepend(str(_ninth_dist(tmp_path / "site")))
        assert "ninthstack" in STACK_REGISTRY.load_plugins()
        yield tmp_path
    sys.modules.pop("ninth_stack", None)


def test_a_ninth_stack_is_one_module_its_policy_loads_and_its_clip_reads(ninth, go2, capsys):
    from sim2real.deploy.cli.policy_export import main as policy_export
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.foreign import known_formats
    from sim2real.deploy.tasks.motion.formats import ClipRequest, read_clip

    assert "ninthstack" in known_formats()
    path = _ninth_policy(ninth / "policy.onnx", go2)
    policy = OnnxPolicy(path, go2)
    assert policy.foreign.format == "ninthstack"
    # its joints by name: the reversed order puts go2's last joint first
    assert policy.spec.action.joints[0] == len(go2.joint_names) - 1
    assert policy_export(["--inspect", str(path), "--robot", "go2"]) == 0
    assert "ninthstack" in capsys.readouterr().out
    clip = ninth / "walk.json"
    frames = {"fps": 50, "joints": list(go2.joint_names), "root": [[0.0, 0.0, 0.3]] * 3}
    clip.write_text(json.dumps(frames | {"q": np.tile(go2.home, (3, 1)).tolist()}))
    request = ClipRequest(clip, None, False, None, None, tuple(go2.joint_names))
    limits = {
        n: (float(go2.position_lower[i]), float(go2.position_upper[i]))
        for i, n in enumerate(go2.joint_names)
    }
    fmt, motion = read_clip(request, "go2", limits)
    assert fmt.name == "ninth_json" and motion.joint_pos.shape == (3, 12)


def test_a_ninth_stack_installed_outside_the_tree_is_read_by_a_fresh_process(tmp_path, go2):
    """No registration in this process: ``policy-export --inspect`` in a new interpreter finds
    the stack by its entry point alone."""
    site = _ninth_dist(tmp_path / "site")
    path = _ninth_policy(tmp_path / "policy.onnx", go2)
    root = Path(__file__).resolve().parent.parent
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), str(root)]))
    code = "from sim2real.deploy.cli.policy_export import main; raise SystemExit(main())"
    out = subprocess.run(
        [sys.executable, "-c", code, "--inspect", str(path), "--robot", "go2"],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "ninthstack" in out.stdout


def test_a_robot_kind_kept_outside_the_tree_registers_through_its_entry_point(
    tmp_path, monkeypatch
):
    """The kinds' registry loads the group ``sim2real.kinds`` as the stacks' loads theirs."""
    from sim2real.deploy.robot_kind import KIND_REGISTRY, kinds

    site = tmp_path / "site"
    (site / "ep_kind-0.1.dist-info").mkdir(parents=True)
    (site / "seam_ep_kind.py").write_text(
        "from sim2real.deploy.kinds import Arm, register_kind\n"
        "register_kind(Arm(name='entry_point_arm'))\n"
    )
    (site / "ep_kind-0.1.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: ep-kind\nVersion: 0.1\n"
    )
    (site / "ep_kind-0.1.dist-info" / "entry_points.txt").write_text(
        "[sim2real.kinds]\nentry_point_arm = seam_ep_kind\n"
    )
    with KIND_REGISTRY.scoped():
        assert "entry_point_arm" not in kinds()
        monkeypatch.syspath_prepend(str(site))
        assert KIND_REGISTRY.load_plugins() == ("entry_point_arm",)
        assert kinds()["entry_point_arm"].name == "entry_point_arm"
    sys.modules.pop("seam_ep_kind", None)
    assert "entry_point_arm" not in kinds()
