"""The import contract: one dependency direction, kernel ← library ← plugins ← applications.

Layers are named by module: ``amslam.apps.*`` applications, ``amslam.plugins.<name>.*`` and
``amslam.trees.*`` plugins (the trees package provides behaviours and mission trees through the
hooks, as a plugin does), ``amslam.lib.*`` the library, ``amslam.testing.*`` the contract kits
(kernel level: plugins' tests use them), everything else under ``amslam`` the kernel. The rules:

* the kernel imports only the kernel;
* the library imports the kernel and the library;
* a plugin imports the kernel, the library and its own modules, never another plugin's;
* applications import anything.

import-linter (grimp) builds its graph by walking the root package's folder, but amslam maps its
packages onto separate top-level folders (``core/``, ``plugins/``, ``trees/``, see
pyproject.toml's ``package-dir``), which it cannot see; so the graph is read here from the
sources' syntax trees: every ``import`` and ``from … import``, at module level or inside a
function (a lazy import is still a dependency).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

#: source folder → the package it holds (pyproject.toml's package-dir)
PACKAGE_DIRS = {"core": "amslam", "plugins": "amslam.plugins", "trees": "amslam.trees"}


@dataclass(frozen=True)
class Violation:
    file: Path
    line: int
    importer: str
    imported: str
    rule: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: {self.importer} imports {self.imported} ({self.rule})"


def layer(module: str) -> tuple[str, str]:
    """``(layer, unit)`` of an amslam module: unit names the plugin for plugins, else the layer."""
    parts = module.split(".")
    if len(parts) >= 3 and parts[1] == "plugins":
        return "plugin", parts[2]
    if len(parts) >= 2 and parts[1] == "plugins":
        return "plugin", ""  # the namespace package itself
    if len(parts) >= 2 and parts[1] == "trees":
        return "plugin", "trees"
    if len(parts) >= 2 and parts[1] == "apps":
        return "application", "apps"
    if len(parts) >= 2 and parts[1] == "lib":
        return "library", "lib"
    if len(parts) >= 2 and parts[1] == "testing":
        return "kits", "testing"
    return "kernel", "kernel"


def allowed(importer: str, imported: str) -> str | None:
    """None if ``importer`` may import ``imported``, else the rule it breaks."""
    (src, src_unit), (dst, dst_unit) = layer(importer), layer(imported)
    if src == "application":
        return None
    if dst == "application":
        return f"a {src} never imports an application"
    if src == "kernel" and dst != "kernel":
        return f"the kernel imports only the kernel, not the {dst}"
    if src == "library" and dst not in ("kernel", "library"):
        return f"the library imports only the kernel and the library, not a {dst}"
    if src == "kits" and dst == "plugin":
        return "the contract kits never import a plugin"
    if src == "plugin" and dst == "plugin" and dst_unit and dst_unit != src_unit:
        return f"plugin {src_unit!r} never imports another plugin ({dst_unit!r}): share it through amslam.lib"
    if src == "plugin" and dst == "kits":
        return "a plugin never imports the contract kits (its tests do)"
    return None


def modules(root: Path) -> Iterator[tuple[Path, str]]:
    """Every source file of the amslam distribution under ``root`` and its module name."""
    for folder, package in PACKAGE_DIRS.items():
        base = root / folder
        for path in sorted(base.rglob("*.py")):
            rel = path.relative_to(base).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            name = ".".join([package, *parts])
            if folder == "core" and parts[:1] in (["plugins"], ["trees"]):
                continue  # not a thing, but never let core/ shadow the other folders
            yield path, name


def imports(path: Path, module: str) -> Iterator[tuple[int, str]]:
    """``(line, imported module)`` of every amslam import in a file, relative ones resolved."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            yield node.lineno, target
            for alias in node.names:  # `from amslam.plugins import sim` imports a plugin module
                yield node.lineno, f"{target}.{alias.name}"


def violations(root: Path) -> list[Violation]:
    """Every import against the layer direction in the sources under ``root``."""
    found: list[Violation] = []
    for path, module in modules(root):
        for line, imported in imports(path, module):
            if found and (found[-1].file, found[-1].line) == (path.relative_to(root), line):
                continue  # one violation per import statement
            if imported != "amslam" and not imported.startswith("amslam."):
                continue
            if imported.count(".") >= 1 and imported.rsplit(".", 1)[0] == "amslam" and _is_symbol(imported):
                continue  # `from amslam import hookimpl`: a name, not a module
            rule = allowed(module, imported)
            if rule:
                found.append(Violation(path.relative_to(root), line, module, imported, rule))
    return found


def _is_symbol(name: str) -> bool:
    """``amslam.X`` where X is a name defined in the kernel package itself, not a subpackage."""
    return name.rsplit(".", 1)[1] in {"hookimpl", "__version__"}
