"""User-facing errors of the pipeline.

An ``AgrivioError`` is a problem with the user's input (a file, a flag, a config): the CLI prints its message,
which names the file and the problem, and exits with status 2 without a traceback. Anything else is a bug and
keeps its traceback.
"""

from __future__ import annotations

from pathlib import Path


class AgrivioError(Exception):
    """A user error: bad input file, bad option, missing data. The message is shown as is."""


class BagError(AgrivioError):
    """A bag file cannot be read as a Rosario bag (missing topic, truncated, empty, inconsistent)."""

    def __init__(self, path: Path | str, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
