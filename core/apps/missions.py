"""Mission tooling (see docs/missions.md), registered through ``amslam_cli_commands``:

    amslam missions                      the packaged missions, one line each
    amslam init NAME [--from MISSION]    NAME.yaml: a copy of a packaged mission to edit
    amslam schema                        the JSON Schema of a mission file, for editors

The schema is pydantic's ``model_json_schema()`` of :class:`amslam.mission.MissionModel` with each
backend section (``platform``, ``mapping``, ...) replaced by the choice of the installed backends'
``Params`` models, each told apart by its ``plugin`` value; so it describes what ``amslam
validate`` accepts with the plugins installed where it is generated. It is written as JSON Schema
draft-07, the draft yaml-language-server (VS Code's YAML extension, Neovim, Helix) validates fully:
pydantic writes draft 2020-12, which differs in what a mission's schema uses only by ``$defs``
(draft-07: ``definitions``) and ``prefixItems`` for tuples (draft-07: ``items`` as a list);
pydantic has no draft-07 mode, so :func:`_as_draft7` renames those two.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from typing import Any, Literal, Union

import amslam
from amslam.cli import Command
from amslam.errors import AmslamError

#: the draft of JSON Schema ``amslam schema`` writes (see the module's doc)
SCHEMA_DIALECT = "http://json-schema.org/draft-07/schema#"
#: the top-level ``name:`` line of a mission file, replaced in a copy by the copy's name
_NAME_LINE = re.compile(r"^name:[^\n]*$", re.MULTILINE)
#: what a mission name may be (``MissionModel.name``): it names the run folders
_MISSION_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


def mission_descriptions() -> dict[str, str]:
    """Each packaged mission's one-line description: its ``description:``, else its first comment."""
    from amslam.mission import packaged_missions, parse_yaml, read_mission_text, resolve_mission_path

    found = {}
    for name in packaged_missions():
        path = resolve_mission_path(name)
        text = read_mission_text(path)
        raw = parse_yaml(text, str(path))
        description = str(raw.get("description") or "").strip() if isinstance(raw, dict) else ""
        if not description:
            comments = [line.lstrip("# ").strip() for line in text.splitlines() if line.startswith("#")]
            description = next((c for c in comments if c), "(no description)")
        found[name] = description
    return found


def cmd_missions(args, registry) -> int:
    descriptions = mission_descriptions()
    width = max(len(name) for name in descriptions)
    for name, description in descriptions.items():
        print(f"{name:<{width}}  {description}")
    print("\nfly one: amslam run NAME; copy one to edit: amslam init MINE --from NAME")
    return 0


def cmd_init(args, registry) -> int:
    from amslam.mission import packaged_missions, read_mission_text, resolve_mission_path

    shipped = packaged_missions()
    if args.source not in shipped:
        raise AmslamError(f"--from {args.source}: no packaged mission of that name ({', '.join(shipped)})")
    target = Path(args.name)
    if target.suffix not in (".yaml", ".yml"):
        target = target.with_name(target.name + ".yaml")
    name = target.stem
    if not _MISSION_NAME.match(name):
        raise AmslamError(
            f"{args.name}: {name!r} cannot be a mission name (letters, digits, '_', '.', '-': it names "
            "the run folders)"
        )
    if not target.parent.is_dir():
        raise AmslamError(f"{target}: no folder {target.parent} to write it in")
    text = _NAME_LINE.sub(f"name: {name}", read_mission_text(resolve_mission_path(args.source)), count=1)
    try:
        with target.open("x", encoding="utf-8") as out:  # "x": never over a file that is there
            out.write(text)
    except FileExistsError:
        raise AmslamError(
            f"{target}: already exists; not overwritten (choose another NAME or remove it)"
        ) from None
    except OSError as exc:
        raise AmslamError(f"cannot write {target}: {exc.strerror or exc}") from None
    print(f"wrote {target} (a copy of the packaged mission {args.source!r}, named {name!r})")
    print(f"check it: amslam validate {target}   fly it: amslam run {target}")
    return 0


def mission_schema(registry) -> dict[str, Any]:
    """The JSON Schema of a mission file with the backends installed in ``registry``."""
    from pydantic import Field, create_model

    from amslam.interfaces import BACKEND_KINDS
    from amslam.mission import DEFAULT_PLUGINS, MissionModel

    sections: dict[str, Any] = {}
    for kind in BACKEND_KINDS:
        variants = []
        for plugin in sorted(registry.backends.get(kind, {})):
            params = registry.backend_class(kind, plugin).Params
            default = DEFAULT_PLUGINS.get(kind)
            plugin_field = (
                (Literal[plugin], Field(plugin, description=f"the {kind} backend (default: {default})"))
                if plugin == default
                else (Literal[plugin], Field(description=f"the {kind} backend"))
            )
            variants.append(
                create_model(f"{kind}_{plugin}", __base__=params, __doc__=params.__doc__, plugin=plugin_field)
            )
        if variants:
            choice = Union[tuple(variants)]  # noqa: UP007 — a union built at run time
            sections[kind] = (choice, Field(default_factory=dict, description=f"the {kind} backend"))
    model = create_model("Mission", __base__=MissionModel, __doc__=MissionModel.__doc__, **sections)
    schema = _as_draft7(model.model_json_schema(ref_template="#/definitions/{model}"))
    schema["definitions"] = schema.pop("$defs", {})
    return {"$schema": SCHEMA_DIALECT, **schema, "title": "amslam mission"}


def _as_draft7(node: Any) -> Any:
    """A pydantic (draft 2020-12) schema node with tuples in draft-07's form: ``prefixItems``
    becomes ``items`` as a list, and a 2020-12 ``items`` beside it (the rest) ``additionalItems``."""
    if isinstance(node, list):
        return [_as_draft7(item) for item in node]
    if not isinstance(node, dict):
        return node
    out = {key: _as_draft7(value) for key, value in node.items()}
    if isinstance(out.get("prefixItems"), list):
        if "items" in out:
            out["additionalItems"] = out.pop("items")
        out["items"] = out.pop("prefixItems")
    return out


def cmd_schema(args, registry) -> int:
    text = json.dumps(mission_schema(registry), indent=2) + "\n"
    if args.out is None:
        sys.stdout.write(text)
        return 0
    from amslam.rundir import write_output

    write_output(Path(args.out), text)
    print(f"mission schema written to {args.out}")
    return 0


def _init_arguments(parser) -> None:
    parser.add_argument("name", help="the new mission: NAME.yaml is written (NAME may be a path)")
    parser.add_argument(
        "--from",
        dest="source",
        default="demo",
        metavar="MISSION",
        help="the packaged mission to copy (default: demo; `amslam missions` lists them)",
    )


def _schema_arguments(parser) -> None:
    parser.add_argument("--out", help="file to write (default: standard output)")


@amslam.hookimpl
def amslam_cli_commands():
    return {
        "missions": Command(
            "list the packaged missions with what each flies", lambda parser: None, cmd_missions
        ),
        "init": Command("write a copy of a packaged mission to edit", _init_arguments, cmd_init),
        "schema": Command(
            "print the JSON Schema of mission files (for editors: yaml-language-server)",
            _schema_arguments,
            cmd_schema,
        ),
    }
