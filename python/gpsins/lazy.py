"""Heavy modules loaded where they are first used, so a command pays only for what it runs
(`gpsins replay` never draws a figure: matplotlib and scipy.stats cost it 0.8 s of imports).

    plt = lazy.module("matplotlib.pyplot", before=lazy.agg_backend)
    chi2 = lazy.name("scipy.stats", "chi2")

The proxy forwards attribute access and calls to the real object, imported on first use.
"""

from __future__ import annotations

import importlib
from typing import Any, Callable


class _Lazy:
    __slots__ = ("_module", "_attr", "_before", "_target")

    def __init__(self, module: str, attr: str | None, before: Callable[[], None] | None):
        object.__setattr__(self, "_module", module)
        object.__setattr__(self, "_attr", attr)
        object.__setattr__(self, "_before", before)
        object.__setattr__(self, "_target", None)

    def _resolve(self) -> Any:
        target = object.__getattribute__(self, "_target")
        if target is None:
            before = object.__getattribute__(self, "_before")
            if before is not None:
                before()
            target = importlib.import_module(object.__getattribute__(self, "_module"))
            attr = object.__getattribute__(self, "_attr")
            if attr is not None:
                target = getattr(target, attr)
            object.__setattr__(self, "_target", target)
        return target

    def __getattr__(self, name: str) -> Any:
        return getattr(self._resolve(), name)

    def __call__(self, *args, **kwargs) -> Any:
        return self._resolve()(*args, **kwargs)

    def __repr__(self) -> str:
        attr = object.__getattribute__(self, "_attr")
        return f"<lazy {object.__getattribute__(self, '_module')}{'.' + attr if attr else ''}>"


def module(name: str, before: Callable[[], None] | None = None) -> Any:
    """The module `name`, imported (after calling `before`) when an attribute is first used."""
    return _Lazy(name, None, before)


def name(module_name: str, attr: str, before: Callable[[], None] | None = None) -> Any:
    """`from module_name import attr`, done when the name is first used (called or an attribute read)."""
    return _Lazy(module_name, attr, before)


def agg_backend() -> None:
    """Figures are files here: matplotlib's Agg backend, chosen before pyplot loads."""
    import matplotlib

    matplotlib.use("Agg")
