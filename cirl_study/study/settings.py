"""The constraints a pipeline's settings obey, written beside the fields they constrain.

A field of a spec (:mod:`cirl_study.study.spec`) is declared with :func:`setting`, which
names the :data:`Check` its value in the file must pass, or with :func:`derived`, which
computes it from settings already read. :meth:`Table.spec` reads a TOML table into a spec
by its fields alone, in their order: the keys the table may have, what each must be, and the
order in which the file is checked are all read from the spec's declaration. Every failure is
one :class:`~cirl_study.errors.UserError` line naming the file and the key::

    pipelines/x.toml: game.learning_steps must be a positive integer, got 0

A check returns the value as the spec stores it, or raises :class:`Invalid` with what the
value must be; it sees the settings read so far (:data:`Known`), so a setting may be
constrained by an earlier one (a start cell by the grid's size).
"""

from __future__ import annotations

import json
import math
from collections import ChainMap
from collections.abc import Callable, Collection, Mapping
from dataclasses import Field, dataclass, field, fields
from types import MappingProxyType
from typing import Any, NoReturn, TypeVar

from cirl_study.errors import UserError

Known = Mapping[str, Any]
"""The settings read before the one being checked: the earlier fields of its table by name,
then the specs of the tables read before it (``known["main"]`` is the parsed ``[main]``)."""

NOTHING_KNOWN: Known = MappingProxyType({})
"""What is known before the first setting of a file is read."""

Check = Callable[[Any, Known], Any]
"""Checks one value of a pipeline file: returns it as the spec stores it, or raises
:class:`Invalid`."""

Spec = TypeVar("Spec")


class Invalid(Exception):
    """A setting's value breaks its constraint: ``must`` is what it must be (``must be a
    positive integer``), ``got`` what it is, as shown after ``, got`` (by default the value,
    :func:`shown`). ``at`` names where the fault lies: for a check, a key below the one checked
    (``oox.cyan`` of ``tasks``), whose value ``got`` then shows; for a derived field, the key
    of its table that makes it impossible (the message then has no ``, got``). ``got = ""``
    shows no value (a key that has no place, a table that misses one)."""

    def __init__(self, must: str, got: str | None = None, at: str | None = None):
        super().__init__(must)
        self.must = must
        self.got = got
        self.at = at


Only = Callable[[Known], "str | None"]
"""Whether a key has a place in a file, from the settings read before it: ``None`` where it
has, else why not, as it follows ``must not be given`` (``with game.features = "tiles"``)."""

_REQUIRED = object()


def setting(
    check: Check,
    *,
    only: Only | None = None,
    otherwise: Callable[[Known], Any] | None = None,
    default: Any = _REQUIRED,
) -> Any:
    """A spec field read from the file's key of the field's name, and held to ``check``.

    ``only`` says where the key has a place (:data:`Only`; everywhere when not given): where
    it has none, giving it is an error and the field is ``otherwise`` of the settings read
    before it (``None`` when not given). ``default`` makes the key optional: its value when
    left out (a file that leaves it out reads as one that writes it).
    """
    metadata: dict[str, Any] = {"check": check}
    if only is not None:
        metadata["only"] = only
        metadata["otherwise"] = otherwise
    if default is not _REQUIRED:
        metadata["default"] = default
    return field(metadata=metadata)


def nested(kind: type, *, only: Only | None = None) -> Any:
    """A spec field read from a table of the file below the spec's own (``[game.tiles]``)
    into the spec ``kind`` by its fields, which see the settings read before it; ``only`` as
    for :func:`setting` (where the table has no place, the field is ``None``)."""
    metadata: dict[str, Any] = {"check": _read_whole, "nested": kind}
    if only is not None:
        metadata["only"] = only
    return field(metadata=metadata)


def _read_whole(value: Any, _known: Known) -> Any:  # pragma: no cover - never called
    """The check of a nested table's field: none, :meth:`Table.spec` reads it by its fields."""
    raise AssertionError("a nested table is read by Table.spec")


def derived(compute: Callable[[Known], Any]) -> Any:
    """A spec field not in the file: ``compute`` makes it from the settings read before it
    (it may raise :class:`Invalid` whose ``at`` names the key of its table that makes it
    impossible, or :class:`UserError`)."""
    return field(metadata={"derive": compute})


def applies(declared: Field[Any], known: Known) -> bool:
    """Whether the key of the field ``declared`` has a place in a file whose earlier settings
    are ``known`` (:data:`Only`)."""
    only = declared.metadata.get("only")
    return only is None or only(known) is None


def written(spec: Any) -> dict[str, Any]:
    """The keys of ``spec``'s table as a pipeline file writes them, in their order: its
    settings, less those without a place in it and the optional ones at their default (so a
    file written from a spec read from a file holds the keys that file had to hold)."""
    values: dict[str, Any] = {}
    known = {f.name: getattr(spec, f.name) for f in fields(spec)}
    for declared in fields(spec):
        if "check" not in declared.metadata or not applies(declared, known):
            continue
        value = getattr(spec, declared.name)
        if "default" in declared.metadata and value == declared.metadata["default"]:
            continue
        values[declared.name] = value
    return values


@dataclass(frozen=True)
class Limits:
    """A closed range ``[low, high]`` of a setting, and why the engine needs it."""

    low: float
    high: float
    reason: str

    def __str__(self) -> str:
        return f"[{self.low:g}, {self.high:g}] ({self.reason})"


def shown(value: Any) -> str:
    """A TOML value as it was probably written, shortened to one short line."""
    if isinstance(value, dict):
        return "a table"
    text = json.dumps(value, default=str)
    return text if len(text) <= 60 else text[:57] + "..."


def is_integer(value: Any) -> bool:
    """An integer of TOML (not a boolean, which Python counts as one)."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_positive_number(value: Any) -> bool:
    """A finite number above 0 (TOML integer or float)."""
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and value > 0
    )


class Table:
    """One TOML table being read; every failure names ``label: prefix.key``."""

    def __init__(self, label: str, prefix: str, data: dict[str, Any], keys: Collection[str]):
        self.label = label
        self.prefix = prefix
        self.data = data
        unknown = sorted(set(data) - set(keys))
        if unknown:
            self.fail(unknown[0], f"is not a known key (expected one of: {', '.join(keys)})")

    def fail(self, key: str, message: str) -> NoReturn:
        raise UserError(f"{self.label}: {self.prefix}{key} {message}")

    def value(self, key: str) -> Any:
        if key not in self.data:
            self.fail(key, "is missing")
        return self.data[key]

    def setting(self, kind: type, key: str, known: Known = NOTHING_KNOWN) -> Any:
        """``table[key]`` held to the constraint of the field ``key`` of the spec ``kind``."""
        (declared,) = (f for f in fields(kind) if f.name == key)
        return self.checked(key, declared.metadata["check"], known)

    def table(self, key: str, keys: Collection[str]) -> Table:
        value = self.value(key)
        if not isinstance(value, dict):
            self.fail(key, f"must be a table ([{self.prefix}{key}]), got {shown(value)}")
        return Table(self.label, f"{self.prefix}{key}.", value, keys)

    def checked(self, key: str, check: Check, known: Known = NOTHING_KNOWN) -> Any:
        """``table[key]`` held to ``check``."""
        value = self.value(key)
        try:
            return check(value, known)
        except Invalid as invalid:
            got = shown(value) if invalid.got is None else invalid.got
            where = key if invalid.at is None else f"{key}.{invalid.at}"
            self.fail(where, f"{invalid.must}, got {got}" if got else invalid.must)

    def spec(self, key: str, kind: type[Spec], known: Known = NOTHING_KNOWN) -> Spec:
        """The table ``key`` read into a ``kind`` by its fields (:func:`setting`,
        :func:`nested`, :func:`derived`), in their order; ``known`` holds the specs read
        before it."""
        declared = fields(kind)  # type: ignore[arg-type]
        table = self.table(key, [f.name for f in declared if "check" in f.metadata])
        read: dict[str, Any] = {}
        seen = ChainMap(read, known)
        for f in declared:
            metadata = f.metadata
            if "derive" in metadata:
                try:
                    read[f.name] = metadata["derive"](seen)
                except Invalid as invalid:
                    table.fail(invalid.at or f.name, invalid.must)
            elif not applies(f, seen):
                if f.name in table.data:
                    table.fail(f.name, f"must not be given {metadata['only'](seen)}")
                otherwise = metadata.get("otherwise")
                read[f.name] = None if otherwise is None else otherwise(seen)
            elif "default" in metadata and f.name not in table.data:
                read[f.name] = metadata["default"]
            elif "nested" in metadata:
                read[f.name] = table.spec(f.name, metadata["nested"], seen)
            else:
                read[f.name] = table.checked(f.name, metadata["check"], seen)
        return kind(**read)


def integer_at_least(minimum: int, what: str) -> Check:
    """An integer ``>= minimum``, ``what`` in words (``a positive integer``)."""

    def check(value: Any, _known: Known) -> int:
        if not is_integer(value) or value < minimum:
            raise Invalid(f"must be {what}")
        return value

    return check


POSITIVE_INTEGER = integer_at_least(1, "a positive integer")


def string(value: Any, _known: Known) -> str:
    """Any string."""
    if not isinstance(value, str):
        raise Invalid("must be a string")
    return value


def boolean(value: Any, _known: Known) -> bool:
    """``true`` or ``false``."""
    if not isinstance(value, bool):
        raise Invalid("must be true or false")
    return value


def one_of(choices: tuple[str, ...]) -> Check:
    """One of the names ``choices``."""

    def check(value: Any, _known: Known) -> str:
        if value not in choices:
            raise Invalid(f"must be one of {', '.join(choices)}")
        return value

    return check


def number_in(limits: Limits | Callable[[Known], Limits]) -> Check:
    """A positive number within ``limits`` (or within the limits the earlier settings give)."""

    def check(value: Any, known: Known) -> float:
        bounds = limits(known) if callable(limits) else limits
        if not (is_positive_number(value) and bounds.low <= value <= bounds.high):
            raise Invalid(f"must be a number in {bounds}")
        return float(value)

    return check


def _distinct(item_ok: Callable[[Any], bool], what: str) -> Callable[[Any], list[Any]]:
    """A non-empty list of distinct values, each passing ``item_ok``."""

    def check(value: Any) -> list[Any]:
        if not isinstance(value, list) or not value or not all(item_ok(v) for v in value):
            raise Invalid(f"must be a non-empty list of {what}")
        if len({float(v) for v in value}) != len(value):
            raise Invalid("must not repeat a value")
        return value

    return check


def positive_integers(value: Any, _known: Known) -> tuple[int, ...]:
    """A non-empty list of distinct positive integers."""
    listed = _distinct(lambda v: is_integer(v) and v > 0, "positive integers")(value)
    return tuple(listed)


def numbers_in(limits: Limits) -> Check:
    """A non-empty list of distinct positive numbers within ``limits``."""
    items = _distinct(
        lambda v: is_positive_number(v) and limits.low <= v <= limits.high,
        f"numbers in {limits}",
    )

    def check(value: Any, _known: Known) -> tuple[float, ...]:
        return tuple(float(v) for v in items(value))

    return check


def names(known_names: Callable[[], Collection[str]], what: str) -> Check:
    """A non-empty list of distinct names from ``known_names()`` (looked up when checked:
    the players' registries load with the first pipeline read)."""

    def check(value: Any, _known: Known) -> tuple[str, ...]:
        choices = known_names()
        if (
            not isinstance(value, list)
            or not value
            or not all(isinstance(v, str) and v in choices for v in value)
            or len(set(value)) != len(value)
        ):
            raise Invalid(
                f"must be a non-empty list of distinct known {what} ({', '.join(choices)})"
            )
        return tuple(value)

    return check
