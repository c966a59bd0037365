"""The project's error types. The CLI maps them to a one-line message and an exit code."""

from __future__ import annotations

#: characters; a message longer than this is cut in the middle (it may quote a huge value from a file)
MAX_MESSAGE = 600


def one_line(text: str) -> str:
    """``text`` with line breaks folded into "; " (third-party messages, e.g. pyarrow's, span lines) and
    cut to :data:`MAX_MESSAGE` characters."""
    s = "; ".join(part.strip() for part in str(text).splitlines() if part.strip())
    if len(s) > MAX_MESSAGE:
        s = f"{s[:MAX_MESSAGE * 2 // 3]} [... {len(s) - MAX_MESSAGE:,} characters ...] {s[-MAX_MESSAGE // 3:]}"
    return s


class RmbuildError(Exception):
    """Base class: an expected failure with a message fit for the user (exit code 1)."""

    exit_code = 1


class InputError(RmbuildError):
    """Bad input or bad usage: a file, row/line and problem (exit code 2).

    ``where`` is e.g. ``"walks/poses.csv:17"``; the message then reads ``"<where>: <problem>"``.
    """

    exit_code = 2

    def __init__(self, problem: str, where: str | None = None) -> None:
        self.problem = one_line(problem)
        self.where = one_line(where) if where else None
        super().__init__(f"{self.where}: {self.problem}" if self.where else self.problem)


class ConfigError(InputError):
    """A config file or config value is invalid (unknown key, wrong type, out of range).

    ``key`` is the dotted key (``map.fill.idw_power``) when the problem is one value; the message then
    reads ``"<where>: <label>: <problem>"`` (``where``: the file, with its line when known; ``label``: the
    key unless given).
    """

    def __init__(self, problem: str, where: str | None = None, key: str | None = None,
                 label: str | None = None) -> None:
        self.key = key
        self.label = label if label is not None else key
        super().__init__(f"{self.label}: {one_line(problem)}" if self.label else problem, where)
        self.problem = one_line(problem)


class WorkspaceError(RmbuildError):
    """The workspace is missing a stage's outputs, or would be overwritten without --force (exit 2)."""

    exit_code = 2


class WorkspaceBusyError(WorkspaceError):
    """Another rmbuild command holds the workspace's lock (exit 75, EX_TEMPFAIL: try again later)."""

    exit_code = 75
