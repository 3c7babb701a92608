"""The reference generator (make docs) writes every hook and interface from the code, deterministically."""

from __future__ import annotations

import importlib.util
import inspect
import re
from pathlib import Path

import pluggy

from amslam import hookspecs
from amslam.interfaces import BACKEND_KINDS

GENERATOR = Path(__file__).resolve().parents[2] / "docs" / "reference" / "generate.py"


def _generator():
    spec = importlib.util.spec_from_file_location("amslam_reference_generator", GENERATOR)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_hook_and_interface_is_documented(tmp_path):
    written = _generator().generate(tmp_path)
    assert {p.name for p in written} == {
        "README.md",
        "hookspecs.md",
        "interfaces.md",
        "types.md",
        "testing.md",
    }
    hooks_md = (tmp_path / "hookspecs.md").read_text()
    pm = pluggy.PluginManager("amslam")
    pm.add_hookspecs(hookspecs)
    names = [n for n, f in inspect.getmembers(hookspecs, inspect.isfunction) if hasattr(f, "amslam_spec")]
    for name in names:
        assert f"| [`{name}`](#{name}) | {hookspecs.since(name)} |" in hooks_md
        section = hooks_md.split(f"### `{name}(", 1)[1].split("\n### ", 1)[0]
        assert f"*Since amslam {hookspecs.since(name)}.*" in section
        assert "Since:" not in section  # shown once, as the line above
    interfaces_md = (tmp_path / "interfaces.md").read_text()
    for kind, base in BACKEND_KINDS.items():
        assert f"## class `{base.__name__}`(Backend)" in interfaces_md, kind
        for method in base.__abstractmethods__:
            assert re.search(rf"\*\*`{method}[(`].*\*\(abstract( property)?\)\*", interfaces_md), (
                kind,
                method,
            )
    testing_md = (tmp_path / "testing.md").read_text()
    for kit in ("PlatformContract", "MappingContract", "SlamContract", "DetectorContract", "PlannerContract"):
        assert f"### class `{kit}`" in testing_md


def test_output_is_deterministic_and_tables_are_well_formed(tmp_path):
    gen = _generator()
    first = {p.name: p.read_text() for p in gen.generate(tmp_path / "a")}
    second = {p.name: p.read_text() for p in gen.generate(tmp_path / "b")}
    assert first == second
    for name, text in first.items():
        assert not re.search(r"0x[0-9a-f]{6,}", text), f"{name} shows a memory address"
        for table in re.findall(r"(?:^\|.*\|\n)+", text, flags=re.M):
            widths = {len(re.findall(r"(?<!\\)\|", row)) for row in table.splitlines()}
            assert len(widths) == 1, f"{name}: ragged table\n{table}"
