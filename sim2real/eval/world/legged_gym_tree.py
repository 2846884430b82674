"""A legged_gym-style config class with everything it inherits, read as text from the tree its
file sits in (:func:`resolve_config`): the task's class, its bases as Python finds them (the
file's imports, absolute ones from the package root above the file that holds the imported
module, relative ones from the file's package; the method resolution order, C3), and each nested
class (``class terrain(LeggedRobotCfg.terrain)``) with its own bases; a nested class the task
does not write is its base's, whole. Nothing is run: every file is parsed with ``ast``.

Each value keeps where it was written (:class:`Setting`: the file relative to the package root
and the line), so that a stored training domain names the file and line of each of its values
(:mod:`sim2real.eval.world.legged_gym_domain`).

A base that cannot be found (a module the tree does not hold, a name the file neither defines
nor imports) is refused in one line naming the class and the module (:class:`TreeError`); no
stack's defaults stand in for a base that is missing. A class without bases is read as it
stands.
"""

from __future__ import annotations

import ast
import os
from dataclasses import dataclass, field
from pathlib import Path

from sim2real.robots.errors import Sim2RealError


class TreeError(Sim2RealError, ValueError):
    """A config whose class or a base of it cannot be found (one line: the class, the module)."""


@dataclass(frozen=True)
class Setting:
    """One value of a resolved config class.

    Attributes:
        value: The literal value (``ast.literal_eval``), or the expression's source text when
            it is not a literal (``literal`` False).
        path: Where it sits in the config, ``domain_rand.friction_range``.
        where: The file (relative to the package root) and line that wrote it,
            ``legged_gym/envs/base/legged_robot_config.py:135``.
        depth: The index in the task class's resolution order of the class that wrote it (0:
            the task's own file; larger: further up its bases).
        literal: Whether ``value`` is a literal.
    """

    value: object
    path: str
    where: str
    depth: int
    literal: bool = True

    def text(self) -> str:
        """``path = value (where)``, for messages and provenance lines."""
        return f"{self.path} = {self.value!r} ({self.where})"


@dataclass
class _Module:
    path: Path
    tree: ast.Module
    classes: dict[str, ast.ClassDef] = field(default_factory=dict)
    #: name -> (module as written, level, the imported name or None for a module alias)
    imports: dict[str, tuple[str, int, str | None]] = field(default_factory=dict)


@dataclass(eq=False)
class _Class:
    node: ast.ClassDef
    module: _Module
    qualname: str
    #: the enclosing class (nested classes), whose body's earlier names a base may use
    outer: _Class | None = None


class ConfigTree:
    """The files of one tree a config class is read from (parsed once each)."""

    def __init__(self, config: Path):
        self.config = config.resolve()
        self.root: Path | None = None  # the package root absolute imports were found under
        self._modules: dict[Path, _Module] = {}
        self._mro: dict[int, list[_Class]] = {}

    # -- files -------------------------------------------------------------------------------

    def module(self, path: Path) -> _Module:
        path = path.resolve()
        if path not in self._modules:
            try:
                text = path.read_text(encoding="utf-8")
            except OSError as exc:
                raise TreeError(f"{path.name}: cannot read ({exc.strerror})") from None
            try:
                tree = ast.parse(text, filename=str(path))
            except (SyntaxError, UnicodeDecodeError) as exc:
                raise TreeError(f"{path.name}: not a Python file: {exc}") from None
            m = _Module(path, tree)
            for node in tree.body:
                if isinstance(node, ast.ClassDef):
                    m.classes[node.name] = node
                elif isinstance(node, ast.ImportFrom):
                    for alias in node.names:
                        m.imports[alias.asname or alias.name] = (
                            node.module or "",
                            node.level,
                            alias.name,
                        )
                elif isinstance(node, ast.Import):
                    for alias in node.names:
                        if alias.asname:
                            m.imports[alias.asname] = (alias.name, 0, None)
                        else:  # import a.b binds a
                            head = alias.name.split(".")[0]
                            m.imports[head] = (head, 0, None)
            self._modules[path] = m
        return self._modules[path]

    def rel(self, path: Path) -> str:
        """``path`` relative to the package root (without an absolute import: to the folder
        that holds every file read; its name when outside it)."""
        common = Path(os.path.commonpath([str(p.parent) for p in self._modules] or [str(path)]))
        for root in (self.root, common, self.config.parent):
            if root is not None:
                try:
                    return path.resolve().relative_to(root).as_posix()
                except ValueError:
                    pass
        return path.name

    def find_module(self, name: str, level: int, importer: Path) -> Path | None:
        """The file of module ``name`` imported from ``importer`` (``level`` dots), or None."""
        parts = [p for p in name.split(".") if p]
        if level:
            base = importer.parent
            for _ in range(level - 1):
                base = base.parent
            return _module_file(base, parts)
        if self.root is not None:
            found = _module_file(self.root, parts)
            if found is not None:
                return found
        for ancestor in importer.parents:
            found = _module_file(ancestor, parts)
            if found is not None:
                if self.root is None:
                    self.root = ancestor
                return found
        return None

    # -- names -------------------------------------------------------------------------------

    def lookup(self, module: _Module, name: str, user: str) -> _Class | _Module:
        """The class or module ``name`` stands for in ``module``.

        Raises:
            TreeError: not defined or imported there, or its module is not in the tree
                (one line naming ``user``, the class that needs it, and the module).
        """
        if name in module.classes:
            return _Class(module.classes[name], module, name)
        if name not in module.imports:
            raise TreeError(
                f"{self.rel(module.path)}: class {user}: its base {name} is neither defined nor "
                "imported in that file"
            )
        written, level, imported = module.imports[name]
        dotted = "." * level + written
        if imported is None:  # import a.b.c [as x]
            found = self.find_module(written, level, module.path)
            if found is None:
                raise _missing(self, user, dotted, module)
            return self.module(found)
        found = self.find_module(written, level, module.path)
        if found is not None:
            target = self.module(found)
            if imported in target.classes or imported in target.imports:
                return self.lookup(target, imported, user)
        sub = self.find_module(f"{written}.{imported}" if written else imported, level, module.path)
        if sub is not None:  # from package import module
            return self.module(sub)
        raise _missing(self, user, dotted, module, imported if found is not None else None)

    def resolve_expr(self, expr: ast.expr, scope: _Class | _Module, user: str) -> _Class:
        """The class a base expression (``Name`` or attribute chain) names.

        Raises:
            TreeError: anything else, or a name not found (named).
        """
        chain: list[str] = []
        node = expr
        while isinstance(node, ast.Attribute):
            chain.insert(0, node.attr)
            node = node.value
        if not isinstance(node, ast.Name):
            raise TreeError(
                f"{self.rel(_mod(scope).path)}: class {user}: base {ast.unparse(expr)} is not a "
                "class name this reader resolves"
            )
        head = node.id
        current: _Class | _Module | None = None
        outer = scope if isinstance(scope, _Class) else None
        while outer is not None and current is None:  # a sibling nested class written before
            nested = _nested_node(outer.node, head)
            if nested is not None and nested.lineno < expr.lineno:
                current = _Class(nested, outer.module, f"{outer.qualname}.{head}", outer)
            outer = outer.outer
        if current is None:
            current = self.lookup(_mod(scope), head, user)
        for attr in chain:
            if isinstance(current, _Module):
                current = self.lookup(current, attr, user)
            else:
                found = self.attribute(current, attr)
                if found is None or not isinstance(found[0], ast.ClassDef):
                    raise TreeError(
                        f"{self.rel(_mod(scope).path)}: class {user}: base "
                        f"{ast.unparse(expr)}: {current.qualname} has no class {attr} (in "
                        f"{self.rel(current.module.path)})"
                    )
                node_, owner = found
                current = _Class(node_, owner.module, f"{owner.qualname}.{attr}", owner)
        if isinstance(current, _Module):
            raise TreeError(
                f"{self.rel(_mod(scope).path)}: class {user}: base {ast.unparse(expr)} is a "
                "module, not a class"
            )
        return current

    def bases(self, cls: _Class) -> list[_Class]:
        return [
            self.resolve_expr(b, cls.outer or cls.module, cls.qualname)
            for b in cls.node.bases
            if not (isinstance(b, ast.Name) and b.id == "object")
        ]

    def mro(self, cls: _Class) -> list[_Class]:
        """C3 linearization of ``cls`` (``object`` left out).

        Raises:
            TreeError: a base not found, or an order Python would refuse (named).
        """
        key = id(cls.node)
        if key not in self._mro:
            bases = self.bases(cls)
            seqs = [list(self.mro(b)) for b in bases] + [list(bases)]
            out = [cls]
            while any(seqs):
                for seq in seqs:
                    if not seq:
                        continue
                    head = seq[0]
                    if not any(_same(head, c) for s in seqs for c in s[1:]):
                        break
                else:
                    raise TreeError(
                        f"{self.rel(cls.module.path)}: class {cls.qualname}: its bases have no "
                        "consistent order (Python refuses it too)"
                    )
                out.append(head)
                seqs = [s[1:] if s and _same(s[0], head) else s for s in seqs]
            self._mro[key] = out
        return self._mro[key]

    def attribute(self, cls: _Class, name: str) -> tuple[ast.AST, _Class] | None:
        """The first definition of ``name`` along ``cls``'s resolution order: ``(node, owner)``
        (an assignment's value or a nested ``ClassDef``), or None."""
        for owner in self.mro(cls):
            node = _own(owner.node).get(name)
            if node is not None:
                return node, owner
        return None

    def settings(self, cls: _Class, prefix: str, top: list[_Class]) -> dict[str, object]:
        """Every name ``cls`` has (its own and inherited): ``{name: Setting}`` for values,
        ``{name: dict}`` for nested classes (recursively), in the base's order first."""
        names: list[str] = []
        for owner in reversed(self.mro(cls)):
            for name in _own(owner.node):
                if name not in names:
                    names.append(name)
        out: dict[str, object] = {}
        for name in names:
            node, owner = self.attribute(cls, name)
            path = f"{prefix}.{name}"
            if isinstance(node, ast.ClassDef):
                nested = _Class(node, owner.module, f"{owner.qualname}.{name}", owner)
                out[name] = self.settings(nested, path, top)
                continue
            try:
                value, literal = ast.literal_eval(node), True
            except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
                value, literal = ast.unparse(node), False
            depth = _depth(owner, top)
            where = f"{self.rel(owner.module.path)}:{node.lineno}"
            out[name] = Setting(value, path, where, depth, literal)
        return out


def _module_file(base: Path, parts: list[str]) -> Path | None:
    if not parts:
        init = base / "__init__.py"
        return init if init.is_file() else None
    stem = base.joinpath(*parts)
    for candidate in (stem.with_suffix(".py"), stem / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _missing(tree: ConfigTree, user: str, dotted: str, module: _Module, name=None) -> TreeError:
    what = f"'{name}' is not in module {dotted}" if name else f"module {dotted} is not in the tree"
    return TreeError(
        f"{tree.rel(module.path)}: class {user}: its base comes from {dotted} and {what} "
        f"(searched from {tree.rel(module.path)} up to the package root): give the config in its "
        "own tree (the folder that holds its base module), not alone"
    )


def _mod(scope: _Class | _Module) -> _Module:
    return scope.module if isinstance(scope, _Class) else scope


def _same(a: _Class, b: _Class) -> bool:
    return a.node is b.node


def _depth(owner: _Class, top: list[_Class]) -> int:
    """The index in the task's resolution order of the top-level class ``owner`` sits in."""
    while owner.outer is not None:
        owner = owner.outer
    return next((i for i, c in enumerate(top) if _same(c, owner)), len(top))


def _nested_node(node: ast.ClassDef, name: str) -> ast.ClassDef | None:
    found = _own(node).get(name)
    return found if isinstance(found, ast.ClassDef) else None


def _own(node: ast.ClassDef) -> dict[str, ast.AST]:
    """The names a class body binds itself: ``{name: value node or ClassDef}`` (the last
    binding wins, as in Python)."""
    out: dict[str, ast.AST] = {}
    for item in node.body:
        if isinstance(item, ast.Assign):
            for target in item.targets:
                if isinstance(target, ast.Name):
                    out[target.id] = item.value
        elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name) and item.value:
            out[item.target.id] = item.value
        elif isinstance(item, ast.ClassDef):
            out[item.name] = item
    return out


@dataclass
class ResolvedConfig:
    """A config class with everything it inherits (:func:`resolve_config`).

    Attributes:
        name: The task's class. file: Its file relative to the package root. root: The package
            root (None: no absolute import was followed). classes: Its resolution order as
            ``"Class (file)"``. values: ``{name: Setting or dict}`` of every name the class has
            (nested classes as dicts, recursively).
        tree: The files read (for other files of the same tree, such as ``legged_robot.py``).
    """

    name: str
    file: str
    root: Path | None
    classes: list[str]
    values: dict
    tree: ConfigTree

    def section(self, name: str) -> dict:
        """The nested class ``name`` as ``{key: Setting or dict}`` (empty when the class has
        none)."""
        found = self.values.get(name)
        return found if isinstance(found, dict) else {}


def _is_config(tree: ConfigTree, c: ast.ClassDef) -> bool:
    names = {i.name for i in c.body if isinstance(i, ast.ClassDef)}
    if names & {"domain_rand", "domain_rands", "noise", "terrain", "commands"}:
        return True
    return any(ast.unparse(b).endswith("Cfg") for b in c.bases) and not any(
        ast.unparse(b).endswith("PPO") for b in c.bases
    )


def resolve_config(path: str | Path, config_class: str | None = None) -> ResolvedConfig:
    """The config class of file ``path`` with everything it inherits (module docstring).

    Args:
        path: The config's Python file (read as text, never run).
        config_class: The class (default: the first top-level class with a ``domain_rand``,
            ``domain_rands``, ``noise``, ``terrain`` or ``commands`` class, else the first that
            derives from a name ending in ``Cfg`` but not ``PPO``).

    Raises:
        TreeError: an unreadable file, not Python, no such class, or a base not found (one
            line naming the class and the module it imports it from).
    """
    path = Path(path)
    tree = ConfigTree(path)
    module = tree.module(path)
    classes = list(module.classes.values())
    if config_class is not None:
        if config_class not in module.classes:
            raise TreeError(
                f"{path}: no class '{config_class}'; expected one of {[c.name for c in classes]}"
            )
        node = module.classes[config_class]
    else:
        chosen = [c for c in classes if _is_config(tree, c)]
        if not chosen:
            raise TreeError(
                f"{path}: no legged_gym config class (a class with a 'domain_rand' or 'noise' "
                f"class, or deriving from LeggedRobotCfg); classes: {[c.name for c in classes]}"
            )
        node = chosen[0]
    cls = _Class(node, module, node.name)
    try:
        top = tree.mro(cls)
        values = tree.settings(cls, "", top)
    except TreeError as exc:  # named from the file the base is missing in; the config's given
        message = str(exc)
        own = f"{tree.rel(path)}: "
        raise TreeError(
            f"{path}: {message[len(own) :]}" if message.startswith(own) else message
        ) from None
    values = {k: _strip(v) for k, v in values.items()}
    return ResolvedConfig(
        name=node.name,
        file=tree.rel(path),
        root=tree.root,
        classes=[f"{c.qualname} ({tree.rel(c.module.path)})" for c in top],
        values=values,
        tree=tree,
    )


def _strip(value):
    """Settings' paths without the leading dot of the class level."""
    if isinstance(value, Setting):
        return Setting(value.value, value.path.lstrip("."), value.where, value.depth, value.literal)
    return {k: _strip(v) for k, v in value.items()}
