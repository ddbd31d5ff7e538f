"""Method registry: `@register(name)` on a class, `get_method(name)` and `build_method(name, given)` for the
runners.

Every module of this package but `base` is one method, named as its module with '_' spelled '-'
(`bop_csv.py` is `--method bop-csv`), so a new method is one new file. It is imported only when asked for,
so a method with heavy or missing dependencies breaks only itself, with an error line that names it (and,
with SYNEEPOSE_DEBUG=1, the traceback of the failed import above it: kernel/cli.py).

A method declares its options once, as a dataclass of `option(...)` fields in its class attribute `Options`;
the command line, its help and the checks below are made from it, and the method is built with one instance.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil

from kernel.cli import DEBUG_ENV
from kernel.errors import UserError

_REGISTRY: dict[str, type] = {}


def option(default=dataclasses.MISSING, help: str = "", *, choices: tuple | None = None,
           within: tuple[float, float] | None = None):
    """An `Options` field: no default makes it required; a given value must be one of `choices` or lie `within`
    (low, high), checked before the method is built. Its type annotation converts the flag's text; a bool is
    a switch that turns it on."""
    return dataclasses.field(default=default, metadata={"help": help, "choices": choices, "within": within})


@dataclasses.dataclass(frozen=True)
class NoOptions:
    """The options of a method that takes none."""


def register(name: str):
    def decorate(cls: type) -> type:
        if not dataclasses.is_dataclass(getattr(cls, "Options", None)):
            raise TypeError(f"method {name!r}: {cls.__name__}.Options must be a dataclass of its options "
                            "(NoOptions when it takes none)")
        cls.name = name
        _REGISTRY[name] = cls
        return cls
    return decorate


def _modules() -> dict[str, str]:
    """Method name -> module, for every method module of this package."""
    return {info.name.replace("_", "-"): f"{__name__}.{info.name}" for info in pkgutil.iter_modules(__path__)
            if info.name != "base"}


def known_methods() -> list[str]:
    return sorted(set(_modules()) | set(_REGISTRY))


def get_method(name: str) -> type:
    module = _modules().get(name)
    if name not in _REGISTRY and module is not None:
        try:
            importlib.import_module(module)
        except Exception as exc:
            raise UserError(f"method {name!r} failed to load: {module}: {type(exc).__name__}: {exc} "
                            f"({DEBUG_ENV}=1 shows the traceback)") from exc
        if name not in _REGISTRY:
            raise UserError(f"method {name!r}: {module} registers no method of that name (@register({name!r}))")
    if name not in _REGISTRY:
        raise UserError(f"unknown method {name!r}; known methods: {', '.join(known_methods())}")
    return _REGISTRY[name]


def flag(field: str) -> str:
    """The command-line flag of an option field."""
    return "--" + field.replace("_", "-")


def required(field: dataclasses.Field) -> bool:
    return field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING


def takes(cls: type) -> str:
    """The flags a method takes, for error messages."""
    return ", ".join(flag(f.name) for f in dataclasses.fields(cls.Options)) or "no options"


def check_option(field: dataclasses.Field, value) -> None:
    """The declared choices and range of one option; a value outside them is a UserError naming its flag."""
    choices, within = field.metadata.get("choices"), field.metadata.get("within")
    if choices is not None and value not in choices:
        raise UserError(f"{flag(field.name)} {value!r} unknown; choose from {', '.join(map(str, choices))}")
    if within is not None and value is not None and not within[0] <= value <= within[1]:
        raise UserError(f"{flag(field.name)} {value}: must lie in {within[0]}..{within[1]}")


def build_method(name: str, given: dict):
    """The method built with the options given (field name -> value; the others take their defaults); an
    option it does not take, a missing one or a value outside its declaration is a UserError."""
    cls = get_method(name)
    fields = {f.name: f for f in dataclasses.fields(cls.Options)}
    for key in given:
        if key not in fields:
            raise UserError(f"method {name!r} does not take {flag(key)}; it takes {takes(cls)}")
    for key, field in fields.items():
        if key in given:
            check_option(field, given[key])
        elif required(field):
            raise UserError(f"method {name!r} needs {flag(key)}")
    return cls(cls.Options(**given))
