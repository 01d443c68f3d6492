"""A validator for the subset of JSON Schema (draft 2020-12) that the log schemas use.

Supported assertion keywords: ``type``, ``enum`` (of scalars; ``true`` is not ``1``),
``required``, ``properties``, ``items``, ``minItems``, ``maxItems``, ``minLength``, ``minimum``,
``maximum``, ``exclusiveMinimum``.
Annotation keywords (``$schema``, ``title``, ``description``, ``contentEncoding``) are ignored.
:func:`unsupported_keywords` lists anything else in a schema, so that a schema using a keyword
this validator would silently skip is caught by the tests.

Why not the ``jsonschema`` package: every record of a run is checked whenever the run is read,
and on the trial record ``jsonschema`` (4.26) takes about 4.6 ms per record against about
0.4 ms here, which would add over a minute to reading the paper run.

JSON types follow the specification: ``true``/``false`` are ``boolean``, never ``number``; an
``integer`` is a number with zero fractional part (so ``2.0`` is an integer).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

ASSERTIONS = frozenset(
    {
        "type",
        "enum",
        "required",
        "properties",
        "items",
        "minItems",
        "maxItems",
        "minLength",
        "minimum",
        "maximum",
        "exclusiveMinimum",
    }
)
ANNOTATIONS = frozenset({"$schema", "title", "description", "contentEncoding"})


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_integer(value: Any) -> bool:
    return type(value) is int or (_is_number(value) and float(value).is_integer())


_TYPES: dict[str, Callable[[Any], bool]] = {
    "null": lambda value: value is None,
    "boolean": lambda value: isinstance(value, bool),
    "string": lambda value: isinstance(value, str),
    "array": lambda value: isinstance(value, list),
    "object": lambda value: isinstance(value, dict),
    "number": _is_number,
    "integer": _is_integer,
}


def _has_type(value: Any, name: str) -> bool:
    return _TYPES[name](value)


def _in_enum(value: Any, options: list[Any]) -> bool:
    """JSON equality with one of ``options`` (scalars): ``true`` is not ``1``, ``1`` is ``1.0``."""
    return any(
        value == option and isinstance(value, bool) == isinstance(option, bool)
        for option in options
    )


def _any_type(names: list[str]) -> Callable[[Any], bool] | None:
    """One predicate for "any of the JSON types ``names``" (``None`` when unconstrained)."""
    if not names:
        return None
    if len(names) == 1:
        return _TYPES[names[0]]
    first, rest = _TYPES[names[0]], _any_type(names[1:])
    return lambda value: first(value) or rest(value)


def schema_errors(instance: Any, schema: dict[str, Any], path: str = "") -> list[str]:
    """Every way ``instance`` fails ``schema``, as ``"path: problem"`` strings (empty if valid)."""
    return list(_errors(instance, schema, path or "record"))


def _errors(value: Any, schema: dict[str, Any], path: str) -> Iterator[str]:
    types = schema.get("type")
    if types is not None:
        names = [types] if isinstance(types, str) else types
        if not any(_has_type(value, name) for name in names):
            yield f"{path}: expected {' or '.join(names)}, got {_json_type(value)}"
            return
    if "enum" in schema and not _in_enum(value, schema["enum"]):
        yield f"{path}: {value!r} is not one of {schema['enum']}"
    is_number = _has_type(value, "number")
    if is_number and "minimum" in schema and value < schema["minimum"]:
        yield f"{path}: {value} is below the minimum {schema['minimum']}"
    if is_number and "maximum" in schema and value > schema["maximum"]:
        yield f"{path}: {value} is above the maximum {schema['maximum']}"
    if is_number and "exclusiveMinimum" in schema and value <= schema["exclusiveMinimum"]:
        yield f"{path}: {value} must be greater than {schema['exclusiveMinimum']}"
    if isinstance(value, str) and len(value) < schema.get("minLength", 0):
        yield f"{path}: shorter than {schema['minLength']} characters"
    if isinstance(value, list):
        if len(value) < schema.get("minItems", 0):
            yield f"{path}: {len(value)} items, at least {schema['minItems']} required"
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            yield f"{path}: {len(value)} items, at most {schema['maxItems']} allowed"
        if "items" in schema:
            for i, item in enumerate(value):
                yield from _errors(item, schema["items"], f"{path}[{i}]")
    if isinstance(value, dict):
        for key in schema.get("required", ()):
            if key not in value:
                yield f"{path}: missing field {key!r}"
        for key, subschema in schema.get("properties", {}).items():
            if key in value:
                yield from _errors(value[key], subschema, f"{path}.{key}")


def _json_type(value: Any) -> str:
    for name in ("null", "boolean", "integer", "number", "string", "array", "object"):
        if _has_type(value, name):
            return name
    return type(value).__name__


def unsupported_keywords(schema: dict[str, Any]) -> set[str]:
    """Keywords anywhere in ``schema`` that this validator neither checks nor ignores by design."""
    found = set(schema) - ASSERTIONS - ANNOTATIONS
    if "items" in schema:
        found |= unsupported_keywords(schema["items"])
    for subschema in schema.get("properties", {}).values():
        found |= unsupported_keywords(subschema)
    return found


def compile_validator(schema: dict[str, Any]) -> Callable[[Any], bool]:
    """A fast yes/no test of an instance against ``schema`` (the rules of :func:`schema_errors`).

    Each schema node becomes one closure, built once, so checking the thousands of cells of a
    run's records costs a few calls each; :func:`schema_errors` then explains a failure.
    """
    types = schema.get("type")
    names = [types] if isinstance(types, str) else list(types or ())
    is_type = _any_type(names)
    has_enum, enum = "enum" in schema, schema.get("enum")
    minimum, maximum = schema.get("minimum"), schema.get("maximum")
    above = schema.get("exclusiveMinimum")
    min_length = schema.get("minLength", 0)
    min_items, max_items = schema.get("minItems", 0), schema.get("maxItems")
    item = compile_validator(schema["items"]) if "items" in schema else None
    required = tuple(schema.get("required", ()))
    properties = tuple((k, compile_validator(s)) for k, s in schema.get("properties", {}).items())

    def check(value: Any) -> bool:
        if (is_type is not None and not is_type(value)) or (has_enum and not _in_enum(value, enum)):
            return False
        if type(value) in (int, float) or _is_number(value):
            return not (
                (minimum is not None and value < minimum)
                or (maximum is not None and value > maximum)
                or (above is not None and value <= above)
            )
        if isinstance(value, list):
            if len(value) < min_items or (max_items is not None and len(value) > max_items):
                return False
            return item is None or all(map(item, value))
        if isinstance(value, dict):
            return all(key in value for key in required) and all(
                key not in value or holds(value[key]) for key, holds in properties
            )
        if isinstance(value, str):
            return len(value) >= min_length
        return True

    return check
