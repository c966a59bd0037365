"""Seeded mutations of text inputs (CSV, tab- or ';'-separated traces, TOML): each returns new bytes and
a short description of what it did."""

from __future__ import annotations

import gzip
from collections.abc import Callable

import numpy as np

#: hostile cell values: empty, NaN/inf spellings, huge/tiny numbers, numbers in other notations, text,
#: control characters, overlong digits, ids that pandas would turn into numbers or NaN
TOKENS = ["", "nan", "NaN", "inf", "-inf", "1e999", "-1e999", "1e308", "-1e308", "1e-308", "0", "-0", "1", "-1",
          "1e9", "1e20", "99999999999999999999", "-99999999999999999999", "0x1F", "1_000", "1,5", "abc", "é",
          "\x00", "   ", "None", "true", "9" * 400, "NA", "00001", "-130", "5", '"', "'", ";", "\t", "\\"]
#: hostile timestamps, for the time field of a line (relative to the line's own time t)
TIMES: list[Callable[[float], str]] = [
    lambda t: "1", lambda t: "0", lambda t: "-1", lambda t: "1e9", lambda t: "1e20", lambda t: "9" * 20,
    lambda t: repr(t + 30 * 86400 * (1000 if t > 1e11 else 1)), lambda t: repr(t - 1e6), lambda t: repr(t * 10),
    lambda t: "nan", lambda t: "", lambda t: repr(t + 0.5),
]
HOSTILE_IDS = ["a/b", "a_b", ".hidden", "NA", "00001", "x" * 300, "../../etc", "con", "Ünïcödé", " sp ace "]


class Lines:
    """A text file as lines (without endings) plus its field separator; serialised back with "\\n"."""

    def __init__(self, data: bytes, sep: str) -> None:
        self.lines = data.decode("utf-8", "surrogateescape").split("\n")
        self.sep = sep

    def data_rows(self, skip_prefix: tuple[str, ...] = ("#", "%")) -> list[int]:
        return [i for i, ln in enumerate(self.lines) if ln and not ln.startswith(skip_prefix)]

    def to_bytes(self) -> bytes:
        return "\n".join(self.lines).encode("utf-8", "surrogateescape")


def _pick(rng: np.random.Generator, seq: list) -> object:
    return seq[int(rng.integers(len(seq)))]


def set_field(lines: Lines, rng: np.random.Generator, i: int, k: int | None, value: str) -> str:
    cells = lines.lines[i].split(lines.sep)
    k = int(rng.integers(len(cells))) if k is None else min(k, len(cells) - 1)
    cells[k] = value
    lines.lines[i] = lines.sep.join(cells)
    return f"line {i + 1} field {k + 1} = {value[:20]!r}"


def mutate_text(data: bytes, sep: str, rng: np.random.Generator, time_field: int | None = None,
                header: bool = False) -> tuple[bytes, str]:
    """One random mutation of a separated text file. ``time_field``: index of the time column (hostile
    times are one of the mutations); ``header``: the first line is a header (kept by most mutations)."""
    lines = Lines(data, sep)
    rows = lines.data_rows()
    if header:
        rows = [r for r in rows if r != 0] or rows
    if not rows:
        return data + b"\xff\n", "garbage"
    i = int(_pick(rng, rows))  # type: ignore[arg-type]
    op = str(_pick(rng, ["cell", "cell", "cell", "time", "time", "drop", "dup", "swap", "truncate", "garbage",
                         "long_line", "long_field", "many_fields", "blank", "crlf", "bom", "empty", "nul",
                         "repeat", "header", "nonutf8"]))
    if op == "cell":
        return _done(lines, "cell " + set_field(lines, rng, i, None, str(_pick(rng, TOKENS))))
    if op == "time" and time_field is not None:
        cells = lines.lines[i].split(sep)
        try:
            t = float(cells[min(time_field, len(cells) - 1)])
        except ValueError:
            t = 0.0
        value = _pick(rng, TIMES)(t)  # type: ignore[operator]
        return _done(lines, "time " + set_field(lines, rng, i, time_field, str(value)))
    if op == "drop":
        del lines.lines[i]
        return _done(lines, f"drop line {i + 1}")
    if op == "dup":
        lines.lines.insert(i, lines.lines[i])
        return _done(lines, f"duplicate line {i + 1}")
    if op == "swap":
        j = int(_pick(rng, rows))  # type: ignore[arg-type]
        lines.lines[i], lines.lines[j] = lines.lines[j], lines.lines[i]
        return _done(lines, f"swap lines {i + 1} and {j + 1}")
    if op == "truncate":
        n = int(rng.integers(len(data) + 1))
        return data[:n], f"truncate at byte {n}"
    if op == "garbage":
        n = int(rng.integers(len(data) + 1))
        junk = bytes(rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8))
        return data[:n] + junk + data[n:], f"{len(junk)} random bytes at byte {n}"
    if op == "long_line":
        lines.lines.insert(i, "9" * (2 << 20))
        return _done(lines, f"2 MB line before line {i + 1}")
    if op == "long_field":
        return _done(lines, "long field " + set_field(lines, rng, i, None, "7" * (1 << 20)))
    if op == "many_fields":
        lines.lines[i] = lines.lines[i] + sep * 100_000
        return _done(lines, f"100,000 extra separators on line {i + 1}")
    if op == "blank":
        lines.lines.insert(i, "")
        return _done(lines, f"blank line before line {i + 1}")
    if op == "crlf":
        return data.replace(b"\n", b"\r\n"), "CRLF line endings"
    if op == "bom":
        return b"\xef\xbb\xbf" + data, "UTF-8 byte order mark"
    if op == "empty":
        return b"", "empty file"
    if op == "nul":
        n = int(rng.integers(len(data) + 1))
        return data[:n] + b"\x00" * 8 + data[n:], f"NUL bytes at byte {n}"
    if op == "repeat":  # up to 20,000 times, at most ~20 MB
        n = max(2, min(20_000, (20 << 20) // max(1, len(lines.lines[i]))))
        lines.lines[i:i + 1] = [lines.lines[i]] * n
        return _done(lines, f"line {i + 1} repeated {n:,} times")
    if op == "header" and header:
        cells = lines.lines[0].split(sep)
        k = int(rng.integers(len(cells)))
        choice = int(rng.integers(3))
        if choice == 0:
            del cells[k]
        elif choice == 1:
            cells[k] = cells[k].upper()
        else:
            cells.append(cells[k])
        lines.lines[0] = sep.join(cells)
        return _done(lines, f"header column {k + 1} {['dropped', 'renamed', 'duplicated'][choice]}")
    n = int(rng.integers(len(data) + 1))
    return data[:n] + b"\xff\xfe\xc3" + data[n:], f"non-UTF-8 bytes at byte {n}"


def _done(lines: Lines, what: str) -> tuple[bytes, str]:
    return lines.to_bytes(), what


def mutate_ids(data: bytes, rng: np.random.Generator, column: int = 0) -> tuple[bytes, str]:
    """Replace every occurrence of one walk id of a CSV table by a hostile id (consistent renaming)."""
    lines = Lines(data, ",")
    ids = sorted({ln.split(",")[column] for ln in lines.lines[1:] if ln})
    if not ids:
        return data, "no ids"
    old = str(_pick(rng, ids))
    new = str(_pick(rng, HOSTILE_IDS))
    for i in range(1, len(lines.lines)):
        cells = lines.lines[i].split(",")
        if len(cells) > column and cells[column] == old:
            cells[column] = new if "," not in new else f'"{new}"'
            lines.lines[i] = ",".join(cells)
    return lines.to_bytes(), f"walk id {old!r} -> {new[:20]!r}"


def gzip_bytes(data: bytes, corrupt: bool, rng: np.random.Generator) -> bytes:
    z = gzip.compress(data, mtime=0)
    if corrupt and len(z) > 20:
        n = int(rng.integers(10, len(z)))
        z = z[:n] + bytes([z[n] ^ 0xFF]) + z[n + 1:] if int(rng.integers(2)) else z[:n]
    return z
