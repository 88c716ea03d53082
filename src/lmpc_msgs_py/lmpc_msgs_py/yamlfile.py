"""Reading the project's YAML files (configs, scene files) with one kind of error text.

Every loader reads a mapping of fields from a file and validates it with a pydantic
model; what goes wrong (unreadable file, bad YAML, not a mapping, a bad field) must
name the file, the field and the reason. The loaders differ only in their error
class and the words for what the file is ("MPC config", "scene file", ...).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import yaml
from pydantic import ValidationError


def read_mapping(path: Path, *, what: str, error: type[Exception]) -> dict[str, Any]:
    """The top-level mapping of a YAML file; ``error`` names the file and the problem.

    An empty file reads as an empty mapping (every field then takes its default).
    """
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"{what} {path}: cannot read it ({exc.strerror or exc})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{what} {path}: not valid YAML ({exc})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise error(f"{what} {path}: expected a mapping of fields at the top level, "
                    f"got {type(data).__name__}")
    return data


def field_path(err: Mapping[str, Any]) -> str:
    """Dotted location of one pydantic error (``<file>`` for the top level)."""
    return ".".join(str(p) for p in err["loc"]) or "<file>"


def first_field_error(what: str, path: Path, exc: ValidationError) -> str:
    """``"<what> <path>: field 'a.b': <reason> (+N more)"`` for the first bad field."""
    err = exc.errors(include_url=False)[0]
    more = exc.error_count() - 1
    return (f"{what} {path}: field '{field_path(err)}': {err['msg']}"
            + (f" (+{more} more)" if more else ""))
