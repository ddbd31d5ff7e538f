"""Method registry: `@register(name)` on a class, `get_method(name)` for the runner.

Built-in methods live in their own modules, imported only when asked for, so a method with heavy or
missing dependencies breaks only itself, with an error that names it."""

from __future__ import annotations

import importlib

from kernel.errors import UserError

BUILTIN = {"bop-csv": "eval.methods.bop_csv", "feepe": "eval.methods.feepe", "handeye": "eval.methods.handeye",
           "ppf": "eval.methods.ppf"}
_REGISTRY: dict[str, type] = {}


def register(name: str):
    def decorate(cls: type) -> type:
        cls.name = name
        _REGISTRY[name] = cls
        return cls
    return decorate


def known_methods() -> list[str]:
    return sorted(set(BUILTIN) | set(_REGISTRY))


def get_method(name: str) -> type:
    if name not in _REGISTRY and name in BUILTIN:
        module = BUILTIN[name]
        try:
            importlib.import_module(module)
        except Exception as exc:
            if isinstance(exc, ModuleNotFoundError) and exc.name == module:
                raise UserError(f"method {name!r} is not available in this checkout ({module} is missing)") from exc
            raise UserError(f"method {name!r} failed to load: {module}: {type(exc).__name__}: {exc}") from exc
    if name not in _REGISTRY:
        raise UserError(f"unknown method {name!r}; known methods: {', '.join(known_methods())}")
    return _REGISTRY[name]
