"""The seams a contributor extends in one module plus one registration line: an after-tick hook
of deploy-run (with its own option and report entry), a physics engine of the plant (chosen by
``--engine`` in deploy-run and the soak), and a robot kind, which makes the decisions of a floating
base outside the physics (the places left testing ``robot.floating_base`` are counted)."""

import json
import re
import sys
import textwrap
from pathlib import Path

import pytest

from sim2real.deploy.backends.sim import engines
from sim2real.deploy.cli.deploy_run import deploy_run_main
from sim2real.deploy.rig import hooks

HOOK_MODULE = '''
"""Counts the ticks the robot spent RUNNING, as a contributor's hook would."""

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.rig.hooks import RunHook, register_hook


class RunningTicks(RunHook):
    name = "running_ticks"

    def __init__(self):
        self.ticks = 0

    def after_tick(self, runtime):
        self.ticks += int(np.count_nonzero(runtime.mode == RUNNING))

    def contribute(self, report):
        report["running_ticks"] = self.ticks


def add_options(parser):
    parser.add_argument("--count-running", action="store_true", help="count RUNNING ticks")


def factory(args, rig):
    return RunningTicks() if args.count_running else None


register_hook("running_ticks", "{module}:factory", add_options)
'''

ENGINE_MODULE = '''
"""The MuJoCo plant stepped with the 4th-order Runge-Kutta integrator: an engine a contributor
adds."""

import mujoco

from sim2real.deploy.backends.sim.plant import SimBackend


class RK4Plant(SimBackend):
    def __init__(self, robot, **kwargs):
        super().__init__(robot, **kwargs)
        for m in self.models:
            m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
'''


def face_types() -> list:
    """Every registry of a robot kind's faces (:class:`sim2real.deploy.core.registry.Faces`),
    their rooms imported: the soak's range defaults, the plant's extras, the film."""
    import sim2real.deploy.backends.sim.plant_faces  # noqa: F401
    import sim2real.eval.film.render  # noqa: F401
    import sim2real.eval.soak.soak_faces  # noqa: F401
    import sim2real.eval.world.session_ranges  # noqa: F401
    import sim2real.eval.world.world_faces  # noqa: F401
    from sim2real.deploy.core.registry import FACE_TYPES

    return list(FACE_TYPES)


def missing_faces() -> list[str]:
    """``"<kind>: <face>"`` for each face type a registered robot kind has no face of, neither
    its own nor one it inherits (``Faces.find`` along its ``lineage()``)."""
    from sim2real.deploy.kinds import KIND_REGISTRY

    kinds = KIND_REGISTRY.entries()
    return [
        f"{name}: {f.what}"
        for name, kind in kinds.items()
        for f in face_types()
        if f.find(kind) is None
    ]


@pytest.fixture(scope="module")
def arm_onnx(tmp_path_factory):
    """The shipped arm policy exported (as ``make run`` does)."""
    from sim2real.deploy.export import export_policy

    folder = tmp_path_factory.mktemp("policy")
    pt = folder / "arm.pt"
    pt.write_bytes(
        (Path(__file__).resolve().parent.parent / "sim2real" / "policies" / "arm.pt").read_bytes()
    )
    return str(export_policy(pt))


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """Writes a module into a folder on sys.path; returns its name. What a test registers is
    forgotten after it (each registry's ``scoped``)."""
    from contextlib import ExitStack

    from sim2real.deploy.kinds import KIND_REGISTRY

    monkeypatch.syspath_prepend(str(tmp_path))
    stack = ExitStack()
    for registry in (hooks.HOOK_REGISTRY, engines.ENGINE_REGISTRY, KIND_REGISTRY, *face_types()):
        stack.enter_context(registry.scoped())

    def write(name: str, text: str) -> str:
        (tmp_path / f"{name}.py").write_text(textwrap.dedent(text).format(module=name))
        return name

    yield write
    stack.close()
    for name in [m for m in sys.modules if m.startswith("seam_")]:
        del sys.modules[name]


def test_a_new_hook_is_one_module_and_one_registration_line(
    plugin, monkeypatch, tmp_path, arm_onnx
):
    module = plugin("seam_running_ticks", HOOK_MODULE)
    registry = hooks.HOOK_REGISTRY
    monkeypatch.setattr(registry, "builtin", (*registry.builtin, module))  # the registration line
    report = tmp_path / "run.json"
    argv = ["--policy", arm_onnx, "--duration", "2", "--report", str(report)]
    assert deploy_run_main([*argv, "--count-running"]) == 0
    run = json.loads(report.read_text())
    # every tick after the ramp-in (the arm starts at home: at once) is a RUNNING one
    ticks = round(run["duration_s"] * run["control_rate_hz"])
    assert 0.9 * ticks < run["running_ticks"] <= ticks
    assert "running_ticks" in run["hook_cost_us"]
    assert deploy_run_main(argv) == 0  # off unless its option is given
    assert "running_ticks" not in json.loads(report.read_text())


def test_a_new_engine_is_one_module_and_one_registration_line(
    plugin, monkeypatch, tmp_path, arm_onnx
):
    module = plugin("seam_rk4", ENGINE_MODULE)
    engines.register_engine("mujoco-rk4", f"{module}:RK4Plant")  # the registration line
    report = tmp_path / "run.json"
    argv = ["--policy", arm_onnx, "--duration", "2", "--report", str(report)]
    assert deploy_run_main([*argv, "--engine", "mujoco-rk4"]) == 0
    rk4 = json.loads(report.read_text())
    assert deploy_run_main(argv) == 0
    euler = json.loads(report.read_text())
    assert rk4["goals"]["issued"] == euler["goals"]["issued"]
    # another integrator: the same run, not the same numbers
    assert rk4["max_joint_speed_rad_s"] != euler["max_joint_speed_rad_s"]
    with pytest.raises(ValueError, match="engine 'ode' is unknown"):
        engines.plant_class("ode")
    with pytest.raises(ValueError, match="registered already"):
        engines.register_engine("mujoco-rk4", f"{module}:RK4Plant")


KIND_MODULE = '''
"""An arm whose joint filters run the constant-velocity model (drives that do not follow their
command closely, e.g. a compliant arm): a kind a contributor adds."""

from sim2real.deploy.kinds import Arm, register_kind

COMPLIANT_ARM = register_kind(Arm(name="compliant_arm", joint_input=False))
'''


def _with_kind(tmp_path, kind: str, robot: str = "arm3") -> Path:
    """A copy of the shipped ``robot``'s folder whose robot.toml says ``kind = "<kind>"``."""
    import shutil

    src = Path(__file__).resolve().parent.parent / "sim2real" / "robots" / robot
    folder = tmp_path / f"{robot}_kind"
    shutil.copytree(src, folder)
    toml = folder / "robot.toml"
    text = toml.read_text()
    toml.write_text(text.replace("\n[control]", f'\nkind = "{kind}"\n\n[control]', 1))
    return toml


def _arm3_with_kind(tmp_path, kind: str):
    from sim2real.robots import load_robot

    return load_robot(str(_with_kind(tmp_path, kind)))


def test_a_new_robot_kind_is_one_module_and_robot_toml_names_it(plugin, monkeypatch, tmp_path):
    from sim2real.deploy import kinds

    robot = _arm3_with_kind(tmp_path, "compliant_arm")
    with pytest.raises(ValueError, match=r"robot.toml: kind = 'compliant_arm': expected one of"):
        kinds.robot_kind(robot)
    module = plugin("seam_compliant_arm", KIND_MODULE)
    __import__(module)  # the registration line
    assert kinds.robot_kind(robot).name == "compliant_arm"
    from sim2real.deploy.safety.guard import SafetyGuard
    from sim2real.deploy.smoothing.smoother import CommandSmoother

    smoother = CommandSmoother(robot, 1, "velocity")
    # the kind's choice reaches the runtime: no commanded acceleration into the joint filters
    assert SafetyGuard(robot, 1, "velocity").estimator_input(smoother) is None
    arm = _arm3_with_kind(tmp_path / "plain", "arm")
    assert SafetyGuard(arm, 1, "velocity").estimator_input(smoother) is not None


FLOATING_KIND_MODULE = '''
"""A legged robot hung from a gantry (a test stand that catches it): a floating-base kind a
contributor adds, which keeps the gantry's tether in the soak (cable pulls) besides pushes. It
notes which of its choices the assembly asked (``ASKED``)."""

from dataclasses import dataclass

from sim2real.deploy.kinds import Legged, register_kind
from sim2real.eval.world.world_faces import WORLD_OF_KIND, FreeWorld

ASKED = []


@dataclass(frozen=True)
class GantryLegged(Legged):
    def state(self, robot, envs):
        ASKED.append("state")
        return super().state(robot, envs)

    def base_stages(self, robot, envs):
        ASKED.append("base_stages")
        return super().base_stages(robot, envs)

    def sensor_frame(self, robot, envs):
        ASKED.append("sensor_frame")
        return super().sensor_frame(robot, envs)

    def wheel_drives(self, robot, envs, mode):
        ASKED.append("wheel_drives")
        return super().wheel_drives(robot, envs, mode)


GANTRY_LEGGED = register_kind(GantryLegged(name="gantry_legged"))
# its faces in the rooms above: a legged robot's (inherited), but a soak world that pulls its
# tether (its own)
WORLD_OF_KIND.register("gantry_legged", FreeWorld(refused=dict()))
'''


def test_a_fourth_kind_floats_through_deploy_run_by_its_own_choices(
    plugin, monkeypatch, tmp_path, go2_onnx
):
    from sim2real.deploy.kinds import KIND_REGISTRY, robot_kind
    from sim2real.robots import load_robot

    toml = _with_kind(tmp_path, "gantry_legged", "go2")
    with pytest.raises(ValueError, match=r"kind = 'gantry_legged': expected one of"):
        robot_kind(load_robot(str(toml)))
    module = plugin("seam_gantry_legged", FLOATING_KIND_MODULE)
    monkeypatch.setattr(KIND_REGISTRY, "builtin", (*KIND_REGISTRY.builtin, module))  # the line
    report = tmp_path / "run.json"
    argv = ["--backend", "sim", "--robot", str(toml.parent), "--policy", str(go2_onnx)]
    argv += ["--command", "0.5,0,0", "--duration", "1.5", "--report", str(report)]
    assert deploy_run_main(argv) == 0
    asked = sys.modules[module].ASKED
    # its base stages, state layout and monitor came from the kind, not from its name or the
    # robot's floating base (a kind named other than "legged" that floats)
    assert {"state", "base_stages", "wheel_drives"} <= set(asked)
    run = json.loads(report.read_text())
    assert run["estimation"] is not None  # the base estimate judged against the truth
    loco = run["locomotion"]
    assert loco["falls"] == 0 and loco["command"] == [[0.5, 0.0, 0.0]]
    assert loco["distance_m"] > 0.2  # it walked forward at the command


def test_robot_toml_kind_must_fit_the_robot(tmp_path):
    from sim2real.deploy.kinds import robot_kind

    with pytest.raises(ValueError, match=r"kind = 'legged' needs a \[base\] table"):
        robot_kind(_arm3_with_kind(tmp_path, "legged"))


def test_a_kind_s_target_and_limit_choices_follow_legged_unless_given():
    from sim2real.deploy.kinds import ARM, LEGGED, RobotKind

    assert not ARM.pd_targets and not ARM.hard_limit_bounce
    assert LEGGED.pd_targets and LEGGED.hard_limit_bounce
    common = {"task": "locomotion", "joint_input": False}
    quadruped = RobotKind(name="quadruped", floating_base=True, **common)
    assert quadruped.pd_targets and quadruped.hard_limit_bounce
    stiff = RobotKind(name="stiff", floating_base=True, pd_targets=False, **common)
    assert not stiff.pd_targets and stiff.hard_limit_bounce


def test_a_kind_with_pd_targets_takes_the_guard_s_envelope_and_the_tracking_tolerance(tmp_path):
    from sim2real.deploy.kinds import ARM, KIND_REGISTRY, Arm, register_kind, robot_kind
    from sim2real.deploy.runtime.anchoring import TRACKING_TOLERANCE, tracking_tolerance
    from sim2real.deploy.safety.guard import SafetyGuard

    arm = _arm3_with_kind(tmp_path / "plain", "arm")
    assert SafetyGuard(arm, 1, "position").envelope is not None
    assert tracking_tolerance(ARM.targets(arm), "position") == TRACKING_TOLERANCE
    with KIND_REGISTRY.scoped():
        register_kind(Arm(name="pd_arm", pd_targets=True))
        robot = _arm3_with_kind(tmp_path, "pd_arm")
        assert SafetyGuard(robot, 1, "position").envelope is None
        assert tracking_tolerance(robot_kind(robot).targets(robot), "position") == float("inf")


#: At most this many places outside the physics test ``floating_base`` (the team's issue: the
#: robot kind decides the rest, :mod:`sim2real.deploy.robot_kind`): the Robot's definition, the
#: kind's check of its robot (its default kind is a table lookup), and the checks of their robot by the rooms
#: beneath the kind's floor (the base estimator's, the spec's observation blocks', the chain
#: bounds').
FLOATING_BASE_PLACES = 5
#: The physics, where a floating base is a free joint: the plant, the importer, and the soak's
#: world (the plant's randomized model: a floating body's IMU, floor and base mass).
PHYSICS = ("sim2real/deploy/backends/sim", "sim2real/robots/importer", "sim2real/eval/world")
#: The Robot's definition of ``floating_base``: one place, however many lines.
DEFINITION = "sim2real/robots/robot.py"


def floating_base_places() -> list[str]:
    """Lines of ``sim2real`` outside :data:`PHYSICS` naming ``floating_base`` in a test (``if``,
    ``and``, ``or``, ``not``, ``else``, ``?``), as ``path:line: text``; the lines of
    :data:`DEFINITION` count as one place (its first). The issue's grep, in Python::

        grep -rn "floating_base" --include=*.py sim2real | grep -v "<PHYSICS>" \\
            | grep -E "if |and |or |not |\\? | else "
    """
    root = Path(__file__).resolve().parent.parent
    test = re.compile(r"if |and |or |not |\? | else ")
    places, definition = [], []
    for path in sorted((root / "sim2real").rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if any(p in rel for p in PHYSICS):
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if rel.startswith(KIND_MODULES) and "robot.floating_base" not in line:
                continue  # the kind's own field of that name: its choice, not the robot's
            if "floating_base" in line and test.search(line):
                out = definition if rel == DEFINITION else places
                out.append(f"{rel}:{number}: {line.strip()}")
    return places + definition[:1]


def test_floating_base_is_tested_outside_the_physics_in_few_places():
    places = floating_base_places()
    assert any(p.startswith(DEFINITION) for p in places)  # the count sees the definition
    assert len(places) <= FLOATING_BASE_PLACES, (
        f"{len(places)} places test floating_base outside the physics (at most "
        f"{FLOATING_BASE_PLACES}): ask the robot kind (sim2real.deploy.robot_kind) instead:\n"
        + "\n".join(places)
    )


#: At most this many lines outside the kinds' modules branch on a robot kind's shape, task or
#: name (the rest is behaviour the kind provides, :class:`sim2real.deploy.robot_kind.RobotKind`).
KIND_BRANCHES = 0
#: The kinds' own modules.
KIND_MODULES = ("sim2real/deploy/robot_kind.py", "sim2real/deploy/kinds/")


#: What :func:`kind_branches` counts, and what it does not.
KIND_ASK = re.compile(r"\.legged\b|kind(\([a-z_.]*\))?\.(floating_base\b|name [!=]=|task [!=]=)")
NOT_KIND = re.compile(r"RobotState\.legged\b|importer\.legged")


def kind_branches() -> list[str]:
    """Lines of ``sim2real`` outside :data:`KIND_MODULES` that ask a kind ``.legged``, its
    ``floating_base``, or compare its ``name`` or ``task``, as ``path:line: text``
    (``RobotState.legged``, the state's constructor, and the importer's ``legged`` module are
    not the kind). In grep::

        grep -rnE '\\.legged\\b|kind(\\([a-z_.]*\\))?\\.(floating_base\\b|name [!=]=|task [!=]=)' \\
            sim2real --include=*.py | grep -vE '^sim2real/deploy/(robot_kind\\.py|kinds/)|RobotState\\.legged\\b|importer\\.legged'
    """
    return lines_outside_the_kinds(KIND_ASK, NOT_KIND)


def lines_outside_the_kinds(ask, unless) -> list[str]:
    """Lines of ``sim2real`` outside :data:`KIND_MODULES` that match the pattern ``ask`` and
    not ``unless``, as ``path:line: text``."""
    root = Path(__file__).resolve().parent.parent
    out = []
    for path in sorted((root / "sim2real").rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel.startswith(KIND_MODULES):
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if ask.search(line) and not unless.search(line):
                out.append(f"{rel}:{number}: {line.strip()}")
    return out


def test_few_lines_branch_on_the_robot_kind_outside_the_kinds():
    lines = kind_branches()
    # the count sees a branch on the task, the shape or the name
    for line in ('if robot_kind(robot).task != "locomotion":', "walks = kind.task == x"):
        assert KIND_ASK.search(line) and not NOT_KIND.search(line)
    assert KIND_ASK.search("if self.kind.floating_base:") and KIND_ASK.search('kind.name == "arm"')
    assert len(lines) <= KIND_BRANCHES, (
        f"{len(lines)} lines branch on the robot kind outside its modules (at most "
        f"{KIND_BRANCHES}): give the kind a choice with a meaning instead:\n" + "\n".join(lines)
    )


def test_the_built_in_kinds_are_one_module_each_and_wheel_legged_is_a_legged_robot():
    """Each built-in kind is its own module, registered by importing :mod:`sim2real.deploy.kinds`
    (no module named by string); a wheel-legged robot makes a legged robot's every choice but its
    name, its wheels its own."""
    from dataclasses import fields

    from sim2real.deploy import kinds

    assert kinds.KIND_REGISTRY.builtin == ()
    assert {"arm", "legged", "wheel_legged", "legged_arm"} <= set(kinds.KIND_REGISTRY.entries())
    assert isinstance(kinds.LEGGED_ARM, kinds.Legged)
    assert isinstance(kinds.WHEEL_LEGGED, kinds.Legged)
    choices = [f.name for f in fields(kinds.LEGGED) if f.name != "name"]
    assert all(getattr(kinds.WHEEL_LEGGED, c) == getattr(kinds.LEGGED, c) for c in choices)
    assert kinds.LEGGED.wheel_drives is not kinds.WHEEL_LEGGED.wheel_drives
    with pytest.raises(NotImplementedError, match="robot kind 'bare': state"):
        kinds.RobotKind("bare", False, "goals", True).state(None, 1)


def test_every_registered_kind_has_a_face_of_every_face_type():
    from sim2real.deploy.kinds import KIND_REGISTRY, register_kind
    from sim2real.deploy.robot_kind import RobotKind

    assert len(face_types()) >= 3  # the soak's range defaults, the plant's extras, the film
    assert missing_faces() == [], "robot kinds without a face:\n" + "\n".join(missing_faces())
    with KIND_REGISTRY.scoped():
        # a kind of its own (no registered kind's class) whose faces nobody registered
        register_kind(RobotKind("faceless", False, "goals", True))
        assert {m.split(":")[0] for m in missing_faces()} == {"faceless"}
        assert len(missing_faces()) == len(face_types())


def test_the_kinds_tasks_are_registered_tasks():
    """Every task a kind may have (``KIND_TASKS``) is one the task registry builds, and each
    registered kind's own; a kind with another task is refused by name."""
    from sim2real.deploy.kinds import KIND_REGISTRY, register_kind
    from sim2real.deploy.robot_kind import KIND_TASKS, RobotKind
    from sim2real.deploy.tasks.task import TASKS

    assert set(KIND_TASKS) <= set(TASKS), (
        f"kind tasks not registered: {set(KIND_TASKS) - set(TASKS)}"
    )
    assert {k.task for k in KIND_REGISTRY.entries().values()} <= set(KIND_TASKS)
    with (
        KIND_REGISTRY.scoped(),
        pytest.raises(ValueError, match="task 'dance' is not one of goals"),
    ):
        register_kind(RobotKind("dancer", False, "dance", True))


def test_faces_inherit_along_the_kind_hierarchy(plugin):
    """A kind takes the faces of the kind it derives from unless it registers its own: the
    wheel-legged and legged-arm robots register none and walk as legged robots; a contributor's
    ``Arm(name=...)`` is an arm to every room; a face of its own wins."""
    from sim2real.deploy.kinds import ARM, LEGGED, LEGGED_ARM, WHEEL_LEGGED, Arm, register_kind

    assert WHEEL_LEGGED.lineage() == ("wheel_legged", "legged")
    assert LEGGED_ARM.lineage() == ("legged_arm", "legged") and LEGGED.lineage() == ("legged",)
    for faces in face_types():
        assert faces.get(WHEEL_LEGGED) is faces.get(LEGGED), faces.what
        assert faces.get(LEGGED_ARM) is faces.get(LEGGED), faces.what
    compliant = register_kind(Arm(name="compliant_arm"))
    assert compliant.lineage() == ("compliant_arm", "arm")
    assert all(f.get(compliant) is f.get(ARM) for f in face_types())
    from sim2real.eval.world.world_faces import WORLD_OF_KIND as world

    world.register("compliant_arm", "its own")
    assert world.get(compliant) == "its own" and world.get(ARM) != "its own"
    with pytest.raises(ValueError, match="robot kind 'wheel_legged' has no soak world"):
        world.get("wheel_legged")  # a bare name asks that name only


#: At most this many lines of the runtime (``sim2real/deploy/runtime/``) test whether a base
#: stage exists (``base_estimator`` or ``fall_detector`` ``is None``): the part of the tick a
#: floating base adds is its kind's stage (``kind.tick_stage``), asked unconditionally; the one
#: left is the stale-sensor report's (whether an IMU went silent).
BASE_STAGE_TESTS = 1


def base_stage_tests() -> list[str]:
    """Lines of ``sim2real/deploy/runtime`` testing ``base_estimator`` or ``fall_detector``
    against None, as ``path:line: text``. In grep::

        grep -rnE '(base_estimator|fall_detector) is (not )?None' sim2real/deploy/runtime
    """
    root = Path(__file__).resolve().parent.parent
    test = re.compile(r"(base_estimator|fall_detector) is (not )?None")
    out = []
    for path in sorted((root / "sim2real" / "deploy" / "runtime").rglob("*.py")):
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if test.search(line):
                out.append(f"{path.relative_to(root).as_posix()}:{number}: {line.strip()}")
    return out


def test_the_runtime_asks_its_kind_s_tick_stage_not_whether_it_has_a_base():
    lines = base_stage_tests()
    assert len(lines) <= BASE_STAGE_TESTS, (
        f"{len(lines)} lines of the runtime test a base stage against None (at most "
        f"{BASE_STAGE_TESTS}): give the kind's tick stage (kind.tick_stage) the work instead:\n"
        + "\n".join(lines)
    )


#: At most this many lines outside the kinds' modules decide by a robot's shape: a kind's flag
#: read (the kind hands out behaviour instead: its drive targets, its tick stage, its faces), a
#: comparison with the locomotion task, ``robot.floating_base`` (the spec's and estimation's
#: checks of their robot, the chain bounds, the soak world's randomized model), or a base stage
#: tested for None (the stale-sensor report, the operator's heading hold, the ROS 2 bridge).
SHAPE_DECISIONS = 11
#: What :func:`shape_decisions` counts (the review's grep, ``shape.sh``).
SHAPE_ASK = re.compile(
    r'task [!=]= "locomotion"|name [!=]= "locomotion"'
    r"|\.(pd_targets|stand_up_on_reset|holds_self_collision|cable_faults|hard_limit_bounce"
    r"|joint_input)\b|kind[a-z_.()]*\.pushes\b"
    r"|robot\.floating_base|(base_estimator|fall_detector) is (not )?None"
)
#: A flag named in a docstring's cross-reference or in the record's own definition.
SHAPE_NOT = re.compile(r":attr:|RobotKind\.")


def shape_decisions() -> list[str]:
    """Lines of ``sim2real`` outside :data:`KIND_MODULES` that decide by a robot's shape
    (:data:`SHAPE_ASK`), as ``path:line: text``."""
    return lines_outside_the_kinds(SHAPE_ASK, SHAPE_NOT)


def test_few_lines_outside_the_kinds_decide_by_the_robot_s_shape():
    lines = shape_decisions()
    # the count sees a flag read, a base stage's None and the robot's floating base
    for line in ("if kind.pd_targets:", "if rt.base_estimator is not None:", "robot.floating_base"):
        assert SHAPE_ASK.search(line)
    assert len(lines) <= SHAPE_DECISIONS, (
        f"{len(lines)} lines outside the kinds decide by the robot's shape (at most "
        f"{SHAPE_DECISIONS}): ask the kind's behaviour (its targets, tick stage, faces):\n"
        + "\n".join(lines)
    )
