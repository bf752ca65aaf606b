"""Hash of the whole code a module depends on, for cache keys that cannot go stale.

A task's result depends on its own module and on every module of the core package
it imports, transitively.  :func:`code_stamp` follows the relative imports of a
source file through the files of its package (on disk, so a copy of the package
hashes its own files) and hashes every file reached, once per process.  Code that calls the compiled kernels
(imports :mod:`..native`) also hashes which kernels this process runs.
"""

import ast
import hashlib
import importlib
from functools import lru_cache
from pathlib import Path

_CORE = Path(__file__).resolve().parent.parent  # nephele/core
_NATIVE = _CORE / "native.py"


def _module_file(base, parts):
    """The ``.py`` file (or package ``__init__.py``) of dotted ``parts`` under ``base``, or None."""
    p = base.joinpath(*parts) if parts else base
    if p.with_suffix(".py").is_file() and parts:
        return p.with_suffix(".py")
    if (p / "__init__.py").is_file():
        return p / "__init__.py"
    return None


@lru_cache(maxsize=4096)
def _relative_imports(source, filename):
    """(level, dotted parts, names) of each relative import in ``source`` (the file's bytes: an edited
    file is parsed again, an unchanged one once per process, whichever stamp reaches it)."""
    out = []
    for node in ast.walk(ast.parse(source, filename=filename)):
        if isinstance(node, ast.ImportFrom) and node.level:
            parts = tuple(node.module.split(".")) if node.module else ()
            out.append((node.level, parts, tuple(alias.name for alias in node.names)))
    return tuple(out)


def _imports(path, root):
    """Files under ``root`` that the relative imports of ``path`` name."""
    out = []
    for level, parts, names in _relative_imports(path.read_bytes(), str(path)):
        base = path.parent
        for _ in range(level - 1):
            base = base.parent
        f = _module_file(base, list(parts))
        if f is not None:
            out.append(f)
        for name in names:  # ``from . import x`` may name a submodule
            g = _module_file(base, [*parts, name])
            if g is not None:
                out.append(g)
    return [f.resolve() for f in out if f.resolve().is_relative_to(root)]


def dependencies(path, root=None):
    """Sorted source files ``path`` depends on under ``root`` (default: its package's top directory)."""
    path = Path(path).resolve()
    root = Path(root).resolve() if root is not None else _CORE
    seen, todo = set(), [path]
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        todo.extend(_imports(f, root))
    return sorted(seen)


@lru_cache(maxsize=None)
def code_stamp(path, root=None):
    """Short sha256 of every file :func:`dependencies` lists (relative names and bytes)."""
    path = Path(path).resolve()
    root = Path(root).resolve() if root is not None else _CORE
    if not path.is_relative_to(root):  # a task registered outside the package: its own folder
        root = path.parent
    h = hashlib.sha256()
    deps = dependencies(path, root)
    for f in deps:
        h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes() + b"\0")
    if _NATIVE in deps:
        # (imported by name: a ``from .. import`` here would make every task depend on it)
        native = importlib.import_module(__package__.rsplit(".", 1)[0] + ".native")
        h.update(b"native\0" + native.identity().encode())
    return h.hexdigest()[:16]
