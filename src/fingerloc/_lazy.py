"""Imports deferred to first use, for a short start-up of the command line (private).

``fingerloc --help`` builds the whole command tree; the command modules name
numpy and rich at module level but use them only when a command runs. A
:class:`LazyModule` stands for a module and imports it on the first
attribute read; :class:`LazyAttr` stands for a class or function of a module
and imports it on the first call. Neither registers anything in
``sys.modules`` before the real import.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

__all__ = ["LazyAttr", "LazyModule"]


class LazyModule:
    """The module ``name``, imported on the first attribute read (then each attribute is kept)."""

    def __init__(self, name: str) -> None:
        self._lazy_name = name

    def __getattr__(self, attr: str) -> Any:
        value = getattr(import_module(self._lazy_name), attr)
        setattr(self, attr, value)  # the next read finds it without this method
        return value

    def __repr__(self) -> str:
        return f"<lazy module {self._lazy_name!r}>"


class LazyAttr:
    """``module.attr`` (a class or a function), imported on the first call."""

    def __init__(self, module: str, attr: str) -> None:
        self._lazy_where = (module, attr)
        self._lazy_target: Any = None

    def resolve(self) -> Any:
        """The real object (importing its module now if needed)."""
        if self._lazy_target is None:
            module, attr = self._lazy_where
            self._lazy_target = getattr(import_module(module), attr)
        return self._lazy_target

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.resolve()(*args, **kwargs)

    def __repr__(self) -> str:
        return f"<lazy {'.'.join(self._lazy_where)}>"
