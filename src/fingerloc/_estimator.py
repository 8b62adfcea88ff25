"""scikit-learn's estimator parameter protocol, without depending on scikit-learn.

The constructor of an estimator stores its arguments untouched under their
own names; :class:`ParamsMixin` then gives ``get_params`` / ``set_params``
(so ``sklearn.base.clone`` works) and a ``__repr__`` that shows the
arguments differing from their defaults. Validation happens in ``fit``.
"""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np

from .errors import InvalidParameterError

__all__ = ["ParamsMixin"]


class ParamsMixin:
    """``get_params`` / ``set_params`` / ``__repr__`` from the constructor's signature."""

    @classmethod
    def _param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [p.name for p in sig.parameters.values() if p.name != "self" and p.kind != p.VAR_KEYWORD]

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The constructor arguments by name, as given (``deep`` is accepted for scikit-learn: no parameter is an estimator)."""
        return {name: getattr(self, name) for name in self._param_names()}

    def set_params(self, **params: Any) -> Any:
        """Set constructor arguments by name; returns self. Unknown names raise :class:`InvalidParameterError`."""
        valid = self._param_names()
        for name, value in params.items():
            if name not in valid:
                raise InvalidParameterError(
                    f"{type(self).__name__} has no parameter {name!r} (known: {', '.join(valid)})"
                )
            setattr(self, name, value)
        return self

    def __repr__(self) -> str:
        sig = inspect.signature(type(self).__init__)
        shown = []
        for name in self._param_names():
            value, default = getattr(self, name), sig.parameters[name].default
            if not _same(value, default):
                shown.append(f"{name}={value!r}")
        return f"{type(self).__name__}({', '.join(shown)})"


def _same(a: Any, b: Any) -> bool:
    if a is b:
        return True
    if type(a) is not type(b) or isinstance(a, np.random.Generator | np.ndarray):
        return False
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return False
