"""Loading JSON documents and turning JSON Schema errors into located, actionable messages."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any

import jsonschema
from jsonschema.exceptions import ValidationError

from harness.errors import InputError, Problem
from harness.paths import schema_path

_JSON_TYPE_NAMES = {
    dict: "object",
    list: "array",
    str: "string",
    bool: "boolean",
    int: "number",
    float: "number",
    type(None): "null",
}


def pointer(path: Any) -> str:
    """RFC 6901 JSON pointer for a path of keys and indices."""
    parts = [str(p).replace("~", "~0").replace("/", "~1") for p in path]
    return "/" + "/".join(parts) if parts else ""


def read_text(path: Path) -> str:
    """A UTF-8 input file's text; a missing or unreadable file is a located InputError."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError([Problem(str(path), "", "no such file")]) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError([Problem(str(path), "", f"cannot read: {exc}")]) from None


def load_json(path: Path) -> Any:
    """Read a JSON file; syntax errors become a located InputError with line and column."""
    text = read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        message = f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        raise InputError([Problem(str(path), "", message)]) from None


@lru_cache(maxsize=None)
def schema(name: str) -> dict:
    return json.loads(schema_path(name).read_text(encoding="utf-8"))


@lru_cache(maxsize=None)
def _validator(name: str) -> jsonschema.Draft202012Validator:
    document = schema(name)
    jsonschema.Draft202012Validator.check_schema(document)
    return jsonschema.Draft202012Validator(document)


def _quoted(values: Any) -> str:
    return ", ".join(json.dumps(v) for v in values)


def _type_name(value: Any) -> str:
    return _JSON_TYPE_NAMES.get(type(value), type(value).__name__)


def _messages(error: ValidationError) -> list[tuple[list, str]]:
    """(path, message) pairs for one schema error; some errors name several locations."""
    path = list(error.absolute_path)
    keyword = error.validator
    value = error.validator_value
    if keyword == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        unknown = [k for k in error.instance if k not in error.schema.get("properties", {})]
        return [
            (path + [key], f"unknown key {json.dumps(key)}; allowed keys: {_quoted(allowed)}")
            for key in unknown
        ]
    if keyword == "required":
        missing = [k for k in value if k not in error.instance]
        return [(path, f"missing required key {json.dumps(k)}") for k in missing]
    if keyword == "enum":
        return [(path, f"{json.dumps(error.instance)} is not allowed; allowed values: {_quoted(value)}")]
    if keyword == "const":
        return [(path, f"{json.dumps(error.instance)} is not allowed; the only allowed value is {json.dumps(value)}")]
    if keyword == "type":
        return [(path, f"expected {value}, got {_type_name(error.instance)} {json.dumps(error.instance)}")]
    if keyword == "minItems":
        return [(path, f"needs at least {value} item(s), has {len(error.instance)}")]
    if keyword == "maxItems":
        return [(path, f"allows at most {value} item(s), has {len(error.instance)}")]
    if keyword == "minLength":
        return [(path, "must not be empty")]
    if keyword == "minProperties":
        return [(path, f"needs at least {value} entry(ies)")]
    if keyword in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        relation = {
            "minimum": "at least",
            "maximum": "at most",
            "exclusiveMinimum": "greater than",
            "exclusiveMaximum": "less than",
        }[keyword]
        return [(path, f"must be {relation} {value}, got {json.dumps(error.instance)}")]
    if keyword == "oneOf":
        kinds = [
            branch.get("properties", {}).get("kind", {}).get("const")
            for branch in value
            if isinstance(branch, dict)
        ]
        if all(kinds) and isinstance(error.instance, dict):
            return [
                (
                    path,
                    f"does not match any form; kind must be one of {_quoted(kinds)}"
                    " with exactly that kind's keys",
                )
            ]
    return [(path, error.message)]


def schema_problems(document: Any, schema_name: str, file: str) -> list[Problem]:
    """Every problem the named schema finds, sorted by location."""
    problems = []
    for error in _validator(schema_name).iter_errors(document):
        for path, message in _messages(error):
            problems.append(Problem(file, pointer(path), message))
    return sorted(set(problems), key=lambda p: (p.pointer, p.message))
