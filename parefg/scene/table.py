"""Reading one TOML table key by key: :class:`Table` and the converters of its values.

A section reader ``take``s every allowed key with a converter (``as_number``,
``one_of(...)``, ...), a default and a check, and ``finish`` reports any leftover key as
unknown.  Errors are one-line :class:`InputError` messages naming the key
(``scene NAME: section.key = value: what is wrong``).  Not collective.
"""

import math

from parefg.errors import InputError

REQUIRED = object()


def show(value) -> str:
    """A value as it appears in an error message: repr, one line, at most 60 characters."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def key_name(key: str) -> str:
    """A key as it appears in an error message: as is if printable, else its repr (one line)."""
    return key if key.isprintable() and len(key) <= 60 else show(key)


class Table:
    """One TOML table under validation: ``take`` each key, then ``finish``."""

    def __init__(self, where: str, path: str, raw):
        if not isinstance(raw, dict):
            raise InputError(f"{where}: {path} = {show(raw)}: must be a table")
        self.where, self.path = where, path
        self.raw = dict(raw)
        self.out: dict = {}
        self.allowed: list[str] = []

    def fail(self, key: str, value, why: str) -> InputError:
        return InputError(f"{self.where}: {self.path}.{key_name(key)} = {show(value)}: {why}")

    def take(self, key: str, convert, default=REQUIRED, check=None):
        """Convert and check ``key``; a missing key gets ``default`` (None: stays absent)."""
        self.allowed.append(key)
        if key not in self.raw:
            if default is REQUIRED:
                raise InputError(f"{self.where}: {self.path}.{key} is required")
            if default is not None:
                self.out[key] = default
            return default
        given = self.raw.pop(key)
        value = convert(self, key, given)
        if check is not None and not check[0](value):
            raise self.fail(key, given, check[1])
        self.out[key] = value
        return value

    def finish(self) -> dict:
        """The effective table; any key not taken is an error listing the allowed ones."""
        for key in self.raw:
            allowed = ", ".join(self.allowed)
            raise InputError(
                f"{self.where}: {self.path}.{key_name(key)}: unknown key (allowed: {allowed})"
            )
        return self.out


def as_number(table: Table, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise table.fail(key, value, "must be a finite number")
    try:
        number = float(value)
    except OverflowError:  # TOML integers have no size limit in tomllib
        number = math.inf
    if not math.isfinite(number):
        raise table.fail(key, value, "must be a finite number")
    return number


def as_integer(table: Table, key: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise table.fail(key, value, "must be an integer")
    return value


def one_of(*options: str):
    """Converter accepting exactly one of ``options`` (plain strings or StrEnum members)."""
    options = tuple(str(option) for option in options)

    def convert(table: Table, key: str, value) -> str:
        if not isinstance(value, str) or value not in options:
            raise table.fail(key, value, "must be one of " + ", ".join(map(repr, options)))
        return value

    return convert


def as_string(table: Table, key: str, value) -> str:
    if not isinstance(value, str) or not value:
        raise table.fail(key, value, "must be a non-empty string")
    return value


def as_names(table: Table, key: str, value) -> list[str]:
    """A list of names; a leading '_' is reserved for parefg's own parts."""
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise table.fail(key, value, "must be a list of non-empty strings")
    if any(v.startswith("_") for v in value):
        raise table.fail(key, value, "names must not start with '_'")
    return list(value)


def as_expression(table: Table, key: str, value):
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise table.fail(key, value, "must be a number or an expression string in x, y, t")
    return value


def as_nonnegative(table: Table, key: str, value):
    """An expression whose value must be >= 0: numbers are checked here, strings at load."""
    value = as_expression(table, key, value)
    if isinstance(value, int | float) and not value >= 0:
        raise table.fail(key, value, "must be >= 0")
    return value


def as_vector(table: Table, key: str, value) -> list:
    if not isinstance(value, list) or len(value) != 2:
        raise table.fail(key, value, "must be a list of two numbers or expression strings")
    return [as_expression(table, f"{key}[{i}]", v) for i, v in enumerate(value)]


def as_pair(table: Table, key: str, value) -> list[float]:
    if not isinstance(value, list) or len(value) != 2:
        raise table.fail(key, value, "must be a list of two numbers")
    return [as_number(table, key, v) for v in value]


def as_points(table: Table, key: str, value) -> list[list[float]]:
    if not isinstance(value, list) or len(value) < 3:
        raise table.fail(key, value, "must be a list of at least 3 points [x, y]")
    return [as_pair(table, key, v) for v in value]


POSITIVE = (lambda v: v > 0, "must be > 0")


def between(low, high):
    return (lambda v: low <= v <= high, f"must be in {low}..{high}")
