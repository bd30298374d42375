"""Errors a user can act on: each names the file and the problem."""

from __future__ import annotations

from pathlib import Path


def brief(items, limit: int = 10, sep: str = ", ") -> str:
    """The first `limit` items joined, with how many more there are: for messages naming frames or fields."""
    items = [str(x) for x in items]
    return sep.join(items[:limit]) + (f" (+{len(items) - limit} more)" if len(items) > limit else "")


class LeovrError(Exception):
    """Base class for errors reported to the user without a traceback."""


class DataError(LeovrError):
    """A dataset file is missing, unreadable or inconsistent."""

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ConfigError(LeovrError):
    """A configuration file or option is invalid."""
