"""Method registry: `@register(name)` on a class, `get_method(name)` for the runner.

Every module of this package but `base` is one method, named as its module with '_' spelled '-'
(`bop_csv.py` is `--method bop-csv`), so a new method is one new file. It is imported only when asked for,
so a method with heavy or missing dependencies breaks only itself, with an error that names it."""

from __future__ import annotations

import importlib
import pkgutil

from kernel.errors import UserError

_REGISTRY: dict[str, type] = {}


def register(name: str):
    def decorate(cls: type) -> type:
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
            raise UserError(f"method {name!r} failed to load: {module}: {type(exc).__name__}: {exc}") from exc
        if name not in _REGISTRY:
            raise UserError(f"method {name!r}: {module} registers no method of that name (@register({name!r}))")
    if name not in _REGISTRY:
        raise UserError(f"unknown method {name!r}; known methods: {', '.join(known_methods())}")
    return _REGISTRY[name]
