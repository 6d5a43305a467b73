"""Expected errors: each one is printed by the CLI as one red line and exits non-zero.

Anything raised that is *not* an :class:`R2SError` is a bug and keeps its traceback.
"""

from __future__ import annotations

from pathlib import Path


class R2SError(Exception):
    """An expected failure with a one-line, user-facing message."""

    exit_code = 1


class InputError(R2SError):
    """The scene's ``input/`` (or another user-supplied file) is missing or malformed.

    The message names the file and what is wrong with it.
    """

    exit_code = 2

    def __init__(self, path: Path | str, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class StageError(R2SError):
    """A stage cannot run, e.g. because an upstream stage has not been run yet."""

    exit_code = 3


class UsageError(R2SError):
    """The command was misused: an unknown stage, option or argument (exit 2, as for the
    command line's own usage errors)."""

    exit_code = 2
