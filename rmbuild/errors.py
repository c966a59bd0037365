"""The project's error types. The CLI maps them to a one-line message and an exit code."""

from __future__ import annotations


class RmbuildError(Exception):
    """Base class: an expected failure with a message fit for the user (exit code 1)."""

    exit_code = 1


class InputError(RmbuildError):
    """Bad input or bad usage: a file, row/line and problem (exit code 2).

    ``where`` is e.g. ``"walks/poses.csv:17"``; the message then reads ``"<where>: <problem>"``.
    """

    exit_code = 2

    def __init__(self, problem: str, where: str | None = None) -> None:
        self.problem = problem
        self.where = where
        super().__init__(f"{where}: {problem}" if where else problem)


class ConfigError(InputError):
    """A config file or config value is invalid (unknown key, wrong type, out of range)."""


class WorkspaceError(RmbuildError):
    """The workspace is missing a stage's outputs, or would be overwritten without --force (exit 2)."""

    exit_code = 2
