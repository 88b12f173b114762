"""The files commands read: scenarios by path or name, mission files (a TST, a scenario or a
command), fleet profiles."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from delegation.errors import InputError, InputProblem


def find_scenario(name: str) -> Path:
    """A scenario by path, or by name under the project's ``scenarios/`` directory.

    Looked up: the path as given; ``scenarios/<name>`` under the working directory and its
    parents; the source checkout this package runs from; ``DELEGATION_SCENARIOS``.
    """
    given = Path(name)
    if given.is_file():
        return given
    names = [given.name] if given.suffix else [f"{given.name}.yaml", f"{given.name}.json"]
    dirs: list[Path] = []
    if os.environ.get("DELEGATION_SCENARIOS"):
        dirs.append(Path(os.environ["DELEGATION_SCENARIOS"]))
    cwd = Path.cwd()
    dirs += [d / "scenarios" for d in (cwd, *cwd.parents)]
    here = Path(__file__).resolve()
    dirs += [d / "scenarios" for d in here.parents]
    dirs.append(here.parents[1] / "scenarios")  # shipped as package data, if ever
    for d in dirs:
        for n in names:
            if (d / n).is_file():
                return d / n
    raise InputError(
        InputProblem(
            name,
            "",
            "no such scenario file (looked in ./scenarios and the project's scenarios/ directory)",
        )
    )


def read_object(path: str) -> dict[str, Any]:
    """A JSON or YAML file holding an object."""
    from delegation.scenario import read_document

    data = read_document(path)
    if not isinstance(data, dict):
        raise InputError(InputProblem(path, "", "must hold a JSON/YAML object"))
    return data


def read_mission(path: str) -> dict[str, Any]:
    """A mission file: a TST, a scenario (its ``mission``) or a start-tst/delegate command; read
    as the operator page reads a mission (`delegation.web.mission_input.tree_in`)."""
    from delegation.web.mission_input import tree_in

    return tree_in(read_object(path), path)


def read_profiles(path: str) -> dict[str, dict[str, Any]]:
    """Fleet profiles from a scenario file (its agents) or a plain object of profiles."""
    from delegation.scenario import load_scenario

    data = read_object(path)
    if "agents" in data:
        return load_scenario(path).profiles()
    kind = ("a command" if isinstance(data.get("command"), str)
            else "a mission (a TST)" if isinstance(data.get("name"), str) else None)
    if kind:  # a profile is an object: a string "name" or "command" is no unit's profile
        raise InputError(InputProblem(
            path, "", f"this is {kind}, not a profiles file: give a scenario (its agents) or "
            "an object of profiles keyed by unit name or agent type"))
    bad = [k for k, v in data.items() if not isinstance(v, dict)]
    if bad:
        raise InputError(
            InputProblem(path, bad[0], "a profile must be an object (speeds, endurance, home, ...)")
        )
    return data

