"""Typed settings read from YAML (presets, sensor profiles) and command-line flags: the shared checks.

Models are strict pydantic v2 and validated from JSON text, so a YAML list stands for a pair and nothing else
is coerced ("16" is not a number); the first error becomes one line naming the dotted key, or the flag that
set it, and the value.
"""

from __future__ import annotations

import json
from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from kernel.errors import UserError


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


def _ordered(r: tuple) -> tuple:
    if r[0] > r[1]:
        raise ValueError(f"range [{r[0]}, {r[1]}] is inverted; give [low, high]")
    return r


def number_range(low: float | None = None, high: float | None = None, exclusive_low: bool = False):
    """A [low, high] pair of numbers, each within the given bounds."""
    bound = Field(gt=low) if exclusive_low else Field(ge=low) if low is not None else Field()
    item = Annotated[float, bound, Field(le=high)] if high is not None else Annotated[float, bound]
    return Annotated[tuple[item, item], AfterValidator(_ordered)]


def int_range(low: int, high: int):
    """A [low, high] pair of integers within the bounds."""
    item = Annotated[int, Field(ge=low, le=high)]
    return Annotated[tuple[item, item], AfterValidator(_ordered)]


def comma_list(text: str, flag: str, noun: str, hint: str, check=None) -> list[str]:
    """A flag's comma-separated names: at least one, each passed to `check` (which raises for an unknown
    one), none twice."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise UserError(f"{flag} {text!r} names no {noun}; {hint}")
    for name in names:
        if check is not None:
            check(name)
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise UserError(f"{flag} names {', '.join(twice)} twice; name each {noun} once")
    return names


def validate(model: type[Section], content: dict, source: str, flags: dict, example: str):
    """`content` as a `model`; `flags` are the command-line values in it (named as --flag in errors),
    `example` the file a user should compare theirs with."""
    try:
        text = json.dumps(content)  # JSON mode: YAML lists stand for pairs, and nothing else is coerced
    except (TypeError, ValueError) as exc:
        raise UserError(f"{source}: {exc}; settings are numbers, strings, booleans, lists and mappings") from None
    try:
        return model.model_validate_json(text)
    except ValidationError as exc:
        raise UserError(_first_error(exc, source, flags, example)) from None


def _first_error(exc: ValidationError, source: str, flags: dict, example: str) -> str:
    """One line: the key as a dotted path (or the command-line flag that set it), its value, what is allowed."""
    error = exc.errors()[0]
    loc = [str(p) for p in error["loc"] if not str(p).startswith(("function-after", "tuple"))]
    key = ".".join(loc)
    more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    if loc and loc[0] in flags:
        return f"--{loc[0]} {flags[loc[0]]!r}: {_lower(error['msg'])}{more}"
    if error["type"] == "extra_forbidden":
        return f"{source}: unknown key {key!r}{more}; see {example} for the keys it holds"
    if error["type"] == "missing":
        return f"{source}: missing key {key!r}{more}; see {example}"
    value = error.get("input")
    return f"{source}: {key} = {json.dumps(value)}: {_lower(error['msg'])}{more}"


def _lower(msg: str) -> str:
    return msg[:1].lower() + msg[1:]
