"""A soak campaign's files carried between its driver and a worker that share no disk.

The Ray executor (:mod:`sim2real.eval.soak.ray_executor`) runs batches on nodes that may not see
the driver's files. What crosses, and how:

- **Inputs** (:func:`pack_inputs`, driver): every file a session opens, in one tar archive that
  travels through Ray's object store: a robot given as a folder or robot.toml (its folder, and its
  MJCF's folder for the meshes), the policy, ``spec``, ``plant_motors``, ``motion`` and the clip
  its contract names, and every file Python opened while the driver loaded the robot and the
  policy (:func:`opened_files`: another stack's contract beside the policy, its ``base.yaml``
  above it, an Isaac Lab run's ``params/env.yaml``, the ONNX's external data). Files of the
  installed packages (a shipped robot, the motor catalog) are not carried: the worker has its own.
  The ranges travel inside the sessions' options (:class:`~sim2real.eval.world.session_ranges.
  SessionRanges`), not as a file.
- A worker extracts them into its own temporary folder ``ROOT`` under their driver paths
  (``ROOT/<absolute driver path>``, :func:`materialise`), works in ``ROOT/<driver's working
  folder>`` so that a relative option names the same file as on the driver, and gives an absolute
  option its path under ``ROOT`` (:func:`worker_config`).
- **Sessions' folders** (``OUT/sessions/<id>/``: checkpoints, progress, results, the film's kept
  checkpoints): to the worker when a campaign resumes (:func:`pack_sessions`,
  :func:`unpack_sessions`); back to the driver as changes (:class:`FolderSync`) after each
  checkpoint and progress report and at the end, which the driver writes into its campaign folder
  (:func:`apply_changes`) as a local run writes them: each file atomically, a checkpoint's arrays
  before its ``checkpoint.json`` (the commit point), ``result.json`` last, removals after.
- The JSON documents that cross (``*.json``, the results) are relabelled (:class:`Relabel`): a
  worker path goes back to the driver's, so checkpoints and results name the files a local run
  names and ``--resume`` and the report read them as a local run's.

Only the standard library (``tarfile``, PEP 578's audit hooks); Ray is not imported here.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
import tarfile
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from sim2real.eval.soak.session import SESSIONS_DIR, SessionConfig, session_dir
from sim2real.robots.errors import Sim2RealError
from sim2real.robots.files import atomic_write

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: The options of :class:`~sim2real.eval.soak.session.SessionConfig` that name files.
PATH_OPTIONS = ("robot", "policy", "spec", "plant_motors", "motion")
#: Folders never carried (a checkout's history, Python's caches).
SKIPPED_DIRS = frozenset({".git", "__pycache__", ".venv"})
#: The system's folders: every node has its own.
SYSTEM_DIRS = ("/proc", "/sys", "/dev", "/etc")
#: Files Python opened to import modules (the worker imports from its own installation).
MODULE_SUFFIXES = (".py", ".pyc", ".so", ".pyd", ".zip")


class TransportError(Sim2RealError, OSError):
    """A campaign's files cannot be packed, extracted or written back; the message names the file."""


# ---------------------------------------------------------------------- what Python opens
_recording: list[set[Path]] = []


def _audit(event: str, args: tuple) -> None:
    if event != "open" or not _recording:
        return
    path = args[0]
    if isinstance(path, (str, bytes, os.PathLike)):
        _recording[-1].add(Path(os.fsdecode(path)))


@contextlib.contextmanager
def opened_files() -> Iterator[set[Path]]:
    """The paths Python's ``open`` (and ``io.open``, ``os.open``) is called with inside the block,
    through an audit hook (PEP 578, ``sys.addaudithook``; installed once per process, idle outside
    the block). Files read by C libraries (ONNX Runtime's, MuJoCo's own) are not seen."""
    if not getattr(opened_files, "installed", False):
        sys.addaudithook(_audit)
        opened_files.installed = True
    seen: set[Path] = set()
    _recording.append(seen)
    try:
        yield seen
    finally:
        _recording.remove(seen)


# ---------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class Inputs:
    """A campaign's input files for a worker.

    Attributes:
        cwd: The driver's working folder (absolute, as ``os.getcwd()`` gives it).
        tar: A tar archive of the files, each under its absolute driver path without the leading
            ``/``.
        files: The absolute driver paths in the archive (for messages and tests).
        resolved: Each absolute path option's value -> its resolved driver path (its path in the
            archive, with a leading ``/``).
    """

    cwd: str
    tar: bytes
    files: tuple[str, ...]
    resolved: dict[str, str]


def _installed_roots() -> list[Path]:
    """Folders every worker has its own copy of: this package, the Python installation and the
    system's (:data:`SYSTEM_DIRS`)."""
    import sim2real

    roots = {Path(sim2real.__file__).resolve().parent, *map(Path, SYSTEM_DIRS)}
    for prefix in {sys.prefix, sys.base_prefix, sys.exec_prefix}:
        roots.add(Path(prefix).resolve())
    return sorted(roots)


def _within(path: Path, roots: list[Path]) -> bool:
    return any(path == r or r in path.parents for r in roots)


def _robot_folders(robot: str) -> list[Path]:
    """The folders of a robot given as a folder or a robot.toml: its folder and, when elsewhere,
    its MJCF's (whose meshes MuJoCo reads); none for a shipped name."""
    from sim2real.robots.loading import resolve_robot_toml

    if not Path(robot).exists():
        return []
    toml = resolve_robot_toml(robot).resolve()
    folders = [toml.parent]
    try:
        mjcf = tomllib.loads(toml.read_text(encoding="utf-8")).get("mjcf")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        mjcf = None  # load_robot has refused it on the driver already
    if isinstance(mjcf, str):
        described = (toml.parent / mjcf).resolve()
        if described.parent != toml.parent and toml.parent not in described.parents:
            folders.append(described.parent)
    return folders


def input_paths(template: SessionConfig, opened=(), policy=None) -> list[Path]:
    """The absolute driver paths of every input of ``template``'s sessions (module docstring).

    Args:
        template: The campaign's options.
        opened: Paths Python opened while the driver loaded the robot and the policy
            (:func:`opened_files`).
        policy: The loaded policy, for the clip its contract names (``foreign.motion.file``).

    Returns:
        Files and folders (carried whole), resolved, outside the installed packages, sorted.
    """
    roots = _installed_roots()
    found: set[Path] = set(_robot_folders(template.robot))
    for name in PATH_OPTIONS[1:]:
        value = getattr(template, name)
        if value is not None:
            found.add(Path(value))
    source = getattr(getattr(policy, "foreign", None), "motion", None)
    if source is not None and getattr(source, "file", None):
        found.add(Path(source.file))
    found.update(Path(p) for p in opened if not str(p).endswith(MODULE_SUFFIXES))
    paths = set()
    for p in found:
        given = Path(os.path.abspath(p))
        p = given.resolve()
        if (p.is_file() or p.is_dir()) and not _within(given, roots) and not _within(p, roots):
            paths.add(p)
    # a file inside a folder carried whole goes with it
    folders = [p for p in paths if p.is_dir()]
    return sorted(p for p in paths if not any(f in p.parents for f in folders))


def _skip(info: tarfile.TarInfo) -> tarfile.TarInfo | None:
    return None if SKIPPED_DIRS & set(Path(info.name).parts) else info


def pack_inputs(template: SessionConfig, opened=(), policy=None) -> Inputs:
    """The campaign's inputs (:func:`input_paths`) in one tar archive, on the driver.

    Raises:
        TransportError: a file that cannot be read (named).
    """
    paths = input_paths(template, opened, policy)
    buffer = io.BytesIO()
    try:
        with tarfile.open(fileobj=buffer, mode="w", dereference=True) as tar:
            for p in paths:
                tar.add(p, arcname=str(p).lstrip("/"), filter=_skip)
    except OSError as exc:
        raise TransportError(f"{exc.filename or paths}: cannot be packed for Ray: {exc}") from None
    resolved = {}
    for name in PATH_OPTIONS:
        value = getattr(template, name)
        if isinstance(value, str) and os.path.isabs(value):  # a shipped robot's name is not
            resolved[value] = str(Path(value).resolve())
    return Inputs(os.getcwd(), buffer.getvalue(), tuple(str(p) for p in paths), resolved)


def _extract(data: bytes, into: Path) -> None:
    if not hasattr(tarfile, "data_filter"):  # pragma: no cover - Python 3.10.12+, 3.11.4+ have it
        raise TransportError(
            f"Python {sys.version.split()[0]}: tarfile has no 'data' extraction filter (PEP 706): "
            "a Ray worker needs Python 3.10.12, 3.11.4 or later"
        )
    with tarfile.open(fileobj=io.BytesIO(data), mode="r") as tar:
        tar.extractall(into, filter="data")  # no absolute paths, no '..', no devices


def materialise(inputs: Inputs, root: str | os.PathLike) -> Path:
    """Extract ``inputs`` under ``root`` (a worker's own folder) and return the folder to work in,
    ``root/<driver's working folder>`` (created)."""
    root = Path(root)
    _extract(inputs.tar, root)
    work = root / inputs.cwd.lstrip("/")
    work.mkdir(parents=True, exist_ok=True)
    return work


def worker_config(config: SessionConfig, inputs: Inputs, root: str | os.PathLike) -> SessionConfig:
    """``config`` on a worker: an absolute path option moved under ``root`` (a relative one names
    the same file from the folder :func:`materialise` returns)."""
    moved = {}
    for name in PATH_OPTIONS:
        value = getattr(config, name)
        if value in inputs.resolved:
            moved[name] = str(root) + inputs.resolved[value]
    return replace(config, **moved)


class Relabel:
    """Paths in the JSON documents that cross: a worker's options (:func:`worker_config`) and any
    path under ``root`` (``to_driver``), and back (``to_worker``).

    Args:
        configs: The sessions' options on the driver.
        inputs: Their inputs (:func:`pack_inputs`).
        root: The worker's folder the inputs are extracted under.
    """

    def __init__(self, configs: list[SessionConfig], inputs: Inputs, root: str | os.PathLike):
        self.root = str(root)
        self.back: dict[str, str] = {}
        for c in configs:
            w = worker_config(c, inputs, root)
            for name in PATH_OPTIONS:
                old, new = getattr(c, name), getattr(w, name)
                if old != new:
                    self.back[new] = old
        self.forth = {v: k for k, v in self.back.items()}

    def _walk(self, doc, strings):
        if isinstance(doc, dict):
            return {k: self._walk(v, strings) for k, v in doc.items()}
        if isinstance(doc, list):
            return [self._walk(v, strings) for v in doc]
        if isinstance(doc, str):
            return strings(doc)
        return doc

    def to_driver(self, doc):
        """``doc`` with a worker option's path back to the driver's option, any other path under
        ``root`` to its driver path."""

        def one(s: str) -> str:
            if s in self.back:
                return self.back[s]
            return s[len(self.root) :] if s.startswith(self.root + "/") else s

        return self._walk(doc, one)

    def to_worker(self, doc):
        """``doc`` with a driver option's absolute path as the worker's."""
        return self._walk(doc, lambda s: self.forth.get(s, s))

    def error(self, exc: BaseException) -> BaseException:
        """``exc`` with the worker's paths in its one-line message as the driver's (its args
        relabelled when they are one string)."""
        if len(exc.args) == 1 and isinstance(exc.args[0], str):
            text = exc.args[0]
            for worker, driver in self.back.items():
                text = text.replace(worker, driver)
            exc.args = (text.replace(self.root + "/", "/"),)
        return exc

    def json_bytes(self, data: bytes, to_driver: bool) -> bytes:
        """A JSON file's bytes relabelled (unchanged when nothing is)."""
        doc = json.loads(data)
        new = self.to_driver(doc) if to_driver else self.to_worker(doc)
        return data if new == doc else json.dumps(new).encode()


# ---------------------------------------------------------------------- sessions' folders
def pack_sessions(out: str | os.PathLike, seeds: list[int]) -> bytes | None:
    """The folders of sessions ``seeds`` in campaign folder ``out`` as a tar archive (paths
    ``sessions/<id>/...``), for a resumed batch; None when none exists."""
    out = Path(out)
    folders = [session_dir(out, s) for s in seeds if session_dir(out, s).is_dir()]
    if not folders:
        return None
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for d in folders:
            tar.add(d, arcname=str(d.relative_to(out)))
    return buffer.getvalue()


def unpack_sessions(data: bytes | None, out: str | os.PathLike, relabel: Relabel) -> None:
    """Extract :func:`pack_sessions`' archive into a worker's campaign folder ``out``, its JSON
    documents relabelled for the worker."""
    if data is None:
        return
    out = Path(out)
    _extract(data, out)
    for path in (out / SESSIONS_DIR).rglob("*.json"):
        raw = path.read_bytes()
        new = relabel.json_bytes(raw, to_driver=False)
        if new is not raw:
            atomic_write(path, new)


def _order(rel: str) -> int:
    """Write order within one change: data, then JSON documents (a checkpoint's manifest is its
    commit point), ``result.json`` (a finished session) last."""
    name = rel.rsplit("/", 1)[-1]
    return 2 if name == "result.json" else 1 if name.endswith(".json") else 0


class FolderSync:
    """What changed in a worker's sessions' folders since the last call (:meth:`changes`).

    Args:
        out: The worker's campaign folder.
        seeds: The sessions of the batch.
        relabel: How their JSON documents go back to the driver.
    """

    def __init__(self, out: str | os.PathLike, seeds: list[int], relabel: Relabel):
        self.out, self.seeds, self.relabel = Path(out), list(seeds), relabel
        self.seen = self._scan()  # what the driver has already (a resumed batch's folders)

    def _scan(self) -> dict[str, tuple[int, int, int]]:
        found = {}
        for seed in self.seeds:
            d = session_dir(self.out, seed)
            if not d.is_dir():
                continue
            for p in d.rglob("*"):
                if p.is_file() and not p.name.endswith(".part"):
                    st = p.stat()
                    key = (st.st_ino, st.st_size, st.st_mtime_ns)
                    found[p.relative_to(self.out).as_posix()] = key
        return found

    def changes(self) -> list[tuple[str, bytes | None]]:
        """``(path relative to the campaign folder, bytes or None for a removal)`` of every file
        written or removed since the last call, in the order :func:`apply_changes` writes them."""
        now = self._scan()
        written = sorted(
            (r for r in now if self.seen.get(r) != now[r]), key=lambda r: (_order(r), r)
        )
        removed = sorted(r for r in self.seen if r not in now)
        self.seen = now
        out = []
        for rel in written:
            data = (self.out / rel).read_bytes()
            if rel.endswith(".json"):
                data = self.relabel.json_bytes(data, to_driver=True)
            out.append((rel, data))
        out.extend((rel, None) for rel in removed)
        return out


def apply_changes(out: str | os.PathLike, changes: list[tuple[str, bytes | None]]) -> None:
    """Write a worker's :meth:`FolderSync.changes` into the driver's campaign folder ``out``: each
    file atomically, in order; a removed file's emptied folders go too (the film's kept
    checkpoints are folders).

    Raises:
        TransportError: a path outside ``out/sessions`` (named).
    """
    out = Path(out)
    sessions = out / SESSIONS_DIR
    for rel, data in changes:
        path = out / rel
        parts = Path(rel).parts
        if Path(rel).is_absolute() or ".." in parts or not parts or parts[0] != SESSIONS_DIR:
            raise TransportError(f"{rel}: a worker's file outside {sessions}")
        if data is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(path, data)
            continue
        path.unlink(missing_ok=True)
        folder = path.parent
        while folder != sessions and sessions in folder.parents:
            try:
                folder.rmdir()
            except OSError:
                break
            folder = folder.parent
