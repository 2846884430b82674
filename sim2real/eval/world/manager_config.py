"""An Isaac Lab or mjlab config written in Python, told apart from a legged_gym config before it
is read as one (:func:`refuse_manager_config`).

legged_gym's configs (legged_gym, HIMLoco, unitree_rl_gym, humanoid-gym) are plain classes whose
nested classes hold literal values: read as text with their bases, they are the values the
training used (:mod:`sim2real.eval.world.legged_gym_tree`). Isaac Lab's and mjlab's are not:
``@configclass`` (Isaac Lab, ``isaaclab.utils.configclass``; ``omni.isaac.lab`` before 2.0) or
``@dataclass`` classes (mjlab) that inherit a task's config (``LocomotionVelocityRoughEnvCfg``,
``LocomotionVelocityEnvCfg``) and change it in ``__post_init__`` (``self.events.push_robot =
None``, ``...params["mass_distribution_params"] = (-1.0, 3.0)``, scaled ranges), or a function
building it (mjlab's ``unitree_go1_rough_env_cfg()``). Their values are what running that code
makes; a static read of the class bodies misses every ``__post_init__`` edit and every call, so it
would store another domain than the training's. What the stack resolved is in the run folder: its
train scripts dump the whole config, inheritance and ``__post_init__`` applied, to
``params/env.yaml``, which :mod:`sim2real.eval.world.env_yaml_domain` reads. Such a file is
refused in one line naming the file, the config and that ``params/env.yaml``.

A file is taken for such a config when it imports Isaac Lab or mjlab (:data:`MANAGER_MODULES`),
or has a class decorated ``@configclass`` or ``@dataclass`` (legged_gym's configs are neither).
The file is parsed (Python's ``ast``), never run.
"""

from __future__ import annotations

import ast
from pathlib import Path

#: Top-level modules of Isaac Lab (2.x ``isaaclab*``; 1.x ``omni.isaac.lab*``) and mjlab whose
#: import marks a config of theirs.
MANAGER_MODULES = ("isaaclab", "omni.isaac.lab", "mjlab")
#: Decorators of a manager-based config class: Isaac Lab's ``configclass``, mjlab's dataclasses.
DECORATORS = ("configclass", "dataclass")


def _stack(module: str) -> str | None:
    """``"Isaac Lab"`` or ``"mjlab"`` for a module of :data:`MANAGER_MODULES` (``isaaclab_tasks``
    too), else None."""
    for prefix in MANAGER_MODULES:
        if module == prefix or module.startswith((prefix + ".", prefix + "_")):
            return "mjlab" if prefix == "mjlab" else "Isaac Lab"
    return None


def _decorator(node: ast.expr) -> str:
    """The last name of a decorator (``configclass``, ``dataclasses.dataclass(...)`` ->
    ``dataclass``)."""
    if isinstance(node, ast.Call):
        node = node.func
    if isinstance(node, ast.Attribute):
        return node.attr
    return node.id if isinstance(node, ast.Name) else ""


def _base(node: ast.expr) -> str:
    return ast.unparse(node)


def manager_config(path: str | Path, tree: ast.Module, config_class: str | None = None):
    """What marks ``tree`` (the parsed file ``path``) as an Isaac Lab or mjlab config, or None:
    ``(stack, config, marks)``; ``stack`` ``"Isaac Lab"``, ``"mjlab"`` or ``"Isaac Lab or
    mjlab"`` (a decorated class without their imports), ``config`` the config named
    (``config_class`` when given and decorated; else the first decorated class whose name ends
    in ``EnvCfg``, else the last decorated class (the one built of the others above it), else a
    top-level function whose name ends in ``_cfg``; None: none found), ``marks`` the reasons
    (imports, decorators) in words."""
    stacks: dict[str, list[str]] = {}
    for node in tree.body:
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names = [node.module]
        else:
            continue
        for name in names:
            stack = _stack(name)
            if stack is not None:
                stacks.setdefault(stack, []).append(name)
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    decorated = [
        (c, d)
        for c in classes
        for d in (_decorator(x) for x in c.decorator_list)
        if d in DECORATORS
    ]
    if not stacks and not decorated:
        return None
    marks = [f"imports {', '.join(dict.fromkeys(v))}" for v in stacks.values()]
    if decorated:
        marks.append(f"@{decorated[0][1]} class {decorated[0][0].name}")
    stack = " and ".join(stacks) if stacks else "Isaac Lab or mjlab"
    chosen = None
    named = [c for c, _ in decorated if c.name == config_class]
    by_name = [c for c, _ in decorated if c.name.endswith("EnvCfg")]
    pick = (named or by_name or [c for c, _ in decorated][-1:] or [None])[0]
    if pick is not None:
        bases = ", ".join(_base(b) for b in pick.bases)
        edits = any(isinstance(f, ast.FunctionDef) and f.name == "__post_init__" for f in pick.body)
        chosen = f"class {pick.name}" + (f"({bases})" if bases else "")
        chosen += " with a __post_init__" if edits else ""
    else:
        funcs = [f for f in tree.body if isinstance(f, ast.FunctionDef) and f.name.endswith("_cfg")]
        chosen = f"function {funcs[0].name}()" if funcs else None
    return stack, chosen, marks


def refuse_manager_config(path: str | Path, config_class: str | None = None) -> str | None:
    """The one-line refusal of ``path`` when it is an Isaac Lab or mjlab config in Python
    (module docstring; :func:`manager_config`), else None (a legged_gym config, or a file that
    does not parse: the legged_gym reader names that)."""
    path = Path(path)
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    except (OSError, SyntaxError, ValueError):
        return None
    found = manager_config(path, tree, config_class)
    if found is None:
        return None
    stack, config, marks = found
    what = f"{config} " if config else ""
    return (
        f"{path}: {what}is an {stack} config in Python ({'; '.join(marks)}), not a legged_gym "
        "config: its values are what running it makes (its bases' and every __post_init__ "
        "edit), which a reading of the file cannot give; give the run folder's params/env.yaml "
        "instead (the config as the stack itself resolved it, written by its train script)"
    )
