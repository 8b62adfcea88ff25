"""The exception hierarchy of fingerloc.

Every error that a user's input, file or parameter can cause is a subclass of
:class:`FingerlocError`. The command line catches exactly this root, prints one
line ``error: ...`` on stderr and exits with code 2; anything else is a bug and
keeps its traceback.
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "DataFormatError",
    "DatabaseError",
    "DatabaseLockedError",
    "EmptyInputError",
    "FingerlocError",
    "InvalidParameterError",
    "NotFittedError",
    "UnknownLetterError",
]


class FingerlocError(Exception):
    """Root of every error fingerloc raises on purpose."""


class InvalidParameterError(FingerlocError, ValueError):
    """A parameter or argument is outside its documented domain.

    The message names the parameter, the constraint and the bad value.
    """


class NotFittedError(FingerlocError, RuntimeError):
    """An estimator was used before ``fit``."""


class DataFormatError(FingerlocError, ValueError):
    """A file or record is malformed.

    Parameters
    ----------
    message : str
        What is wrong, naming the bad value.
    path : str or Path, optional
        The file that holds the bad record.
    line : int, optional
        1-based line number of the bad record in ``path``.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        line: int | None = None,
    ) -> None:
        self.message = message
        self.path = None if path is None else str(path)
        self.line = line
        super().__init__(self._format())

    def _format(self) -> str:
        where = ""
        if self.path is not None:
            where = self.path
            if self.line is not None:
                where += f":{self.line}"
            where += ": "
        elif self.line is not None:
            where = f"line {self.line}: "
        return where + self.message

    def at(self, *, path: str | Path | None = None, line: int | None = None) -> DataFormatError:
        """Return a copy of this error located at ``path`` and ``line``."""
        err = type(self).__new__(type(self))
        DataFormatError.__init__(
            err,
            self.message,
            path=self.path if path is None else path,
            line=self.line if line is None else line,
        )
        return err


class EmptyInputError(DataFormatError):
    """A file or collection that must hold at least one record holds none."""


class UnknownLetterError(DataFormatError):
    """A fingerprint string holds a letter outside the fingerprint alphabet."""


class DatabaseError(FingerlocError):
    """A place database is missing, corrupt, foreign or of another version."""


class DatabaseLockedError(DatabaseError):
    """Another process held a place database's writer lock longer than the caller would wait."""
