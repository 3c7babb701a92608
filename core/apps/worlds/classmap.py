"""The class map: which imported models become objects of which amslam class.

A YAML file of ordered ``pattern: class`` rules (see ``default_class_map.yaml``, the packaged
default, for the pattern syntax). The first rule that matches a model's instance name or its
model name decides; no match means building structure.
"""

from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import yaml

from amslam.errors import AmslamError

#: classes with a meaning of their own rather than an object class
STRUCTURE = "structure"
SKIP = "skip"

DEFAULT_MAP_NAME = "default_class_map.yaml"

_CAMEL = re.compile(r"(?<=[a-z])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])|(?<=[A-Za-z])(?=\d)|(?<=\d)(?=[A-Za-z])")


def words(name: str) -> str:
    """A name split into lower-case words joined by ``_``: ``'OfficeChair2'`` → ``'office_chair_2'``."""
    spaced = _CAMEL.sub("_", name)
    return "_".join(w for w in re.split(r"[^A-Za-z0-9]+", spaced) if w).lower()


@dataclass(frozen=True)
class Rule:
    pattern: str
    cls: str

    def matches(self, name: str) -> bool:
        if self.pattern.startswith("re:"):
            return re.search(self.pattern[3:], name) is not None
        split = words(name)
        if any(c in self.pattern for c in "*?["):
            return fnmatch.fnmatchcase(split, self.pattern.lower())
        wanted = words(self.pattern)
        return re.search(rf"(?:^|_){re.escape(wanted)}(?:_|$)", split) is not None


@dataclass(frozen=True)
class ClassMap:
    rules: tuple[Rule, ...]
    source: str

    def classify(self, *names: str) -> tuple[str, str] | None:
        """``(class, pattern)`` of the first rule matching any of ``names``, or None."""
        for rule in self.rules:
            if any(rule.matches(n) for n in names if n):
                return rule.cls, rule.pattern
        return None


def default_map_text() -> str:
    return resources.files("amslam.apps.worlds").joinpath(DEFAULT_MAP_NAME).read_text()


def _rules_from(data: object, where: str) -> tuple[list[Rule], bool]:
    if not isinstance(data, dict) or not isinstance(data.get("classes"), dict):
        raise AmslamError(f"{where}: a class map needs a 'classes:' mapping of pattern: class")
    unknown = set(data) - {"classes", "extends"}
    if unknown:
        raise AmslamError(
            f"{where}: unknown key(s) {sorted(unknown)} (a class map has 'classes' and 'extends')"
        )
    extends = data.get("extends")
    if extends not in (None, "default"):
        raise AmslamError(f"{where}: 'extends' can only be 'default', not {extends!r}")
    rules = []
    for pattern, cls in data["classes"].items():
        if not isinstance(cls, str) or not cls.strip():
            raise AmslamError(f"{where}: pattern {pattern!r} needs a class name, got {cls!r}")
        pattern = str(pattern)
        if pattern.startswith("re:"):
            try:
                re.compile(pattern[3:])
            except re.error as exc:
                raise AmslamError(
                    f"{where}: pattern {pattern!r} is not a valid regular expression: {exc}"
                ) from None
        rules.append(Rule(pattern, cls.strip()))
    return rules, extends == "default"


def load_class_map(path: Path | None = None) -> ClassMap:
    """The class map in ``path``, or the packaged default."""
    if path is None:
        rules, _ = _rules_from(yaml.safe_load(default_map_text()), "default class map")
        return ClassMap(tuple(rules), "default")
    if not path.is_file():
        raise AmslamError(f"class map not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f":{mark.line + 1}" if mark is not None else ""
        raise AmslamError(f"{path}{at}: not valid YAML: {getattr(exc, 'problem', exc)}") from None
    rules, extends = _rules_from(data, str(path))
    if extends:
        rules += list(load_class_map().rules)
    return ClassMap(tuple(rules), str(path))
