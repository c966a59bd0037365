"""Input files that may be gzip-compressed, read with a bound on what they expand to.

A file whose name ends in ``.gz`` is decompressed as it is read; past :data:`MAX_GUNZIP_BYTES` of output
the read stops with an :class:`InputError` naming the file and the limit (a "gzip bomb" of a few MB can
expand to GBs). Plain files are read as they are.
"""

from __future__ import annotations

import errno
import gzip
import io
import os
import stat
import zlib
from pathlib import Path

from rmbuild.errors import InputError
from rmbuild.limits import MAX_GUNZIP_BYTES


def is_gzip_name(path: str | Path) -> bool:
    return str(path).lower().endswith(".gz")


class ExpandsTooFar(Exception):
    """Raised by :class:`_Bounded` past its limit (not an OSError: libraries that catch those must not)."""

    def __init__(self, path: Path, limit: int) -> None:
        self.path, self.limit = path, limit
        super().__init__(f"{path}: decompresses to more than {limit / 2**20:g} MB")

    def input_error(self) -> InputError:
        return InputError(f"gzip data expands to more than {self.limit / 2**20:g} MB (the limit of a compressed "
                          "input file; decompress it and give the plain file)", str(self.path))


class _Bounded(io.RawIOBase):
    """A binary reader over a decompressing stream that raises :class:`ExpandsTooFar` past ``limit`` bytes."""

    def __init__(self, raw: io.BufferedIOBase, path: Path, limit: int) -> None:
        self._raw, self._path, self._limit, self._n = raw, path, limit, 0

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:  # type: ignore[no-untyped-def,override]
        n = self._raw.readinto(b)
        self._n += n or 0
        if self._n > self._limit:
            raise ExpandsTooFar(self._path, self._limit)
        return n

    def close(self) -> None:
        try:
            self._raw.close()
        finally:
            super().close()


def read_at_most(path: str | Path, limit: int) -> bytes:
    """The first ``limit + 1`` bytes of the file ``path`` at most (so a result longer than ``limit`` means the
    file is over it). The size is not taken from the file's metadata, which a pipe has not; a device (``/dev/zero``,
    a link to one) is refused. OSError as ``open`` raises it, or "not a regular file"."""
    with Path(path).open("rb") as fh:
        mode = os.fstat(fh.fileno()).st_mode
        if not (stat.S_ISREG(mode) or stat.S_ISFIFO(mode)):
            raise OSError(errno.EINVAL, "not a regular file")
        return fh.read(limit + 1)


def open_binary(path: str | Path, limit: int = MAX_GUNZIP_BYTES) -> io.BufferedReader:
    """The file as a binary stream, decompressed when its name ends in .gz (at most ``limit`` bytes: past it
    a read raises :class:`ExpandsTooFar`)."""
    p = Path(path)
    if not is_gzip_name(p):
        return p.open("rb")
    return io.BufferedReader(_Bounded(gzip.open(p, "rb"), p, limit), buffer_size=1 << 16)  # type: ignore[arg-type]


def read_bytes(path: str | Path, limit: int, what: str = "file") -> bytes:
    """The whole file (gunzipped when its name ends in .gz), at most ``limit`` bytes after decompression
    (and never more than :data:`MAX_GUNZIP_BYTES` of gzip output); InputError naming the file otherwise."""
    p = Path(path)
    try:
        if not is_gzip_name(p):
            data = read_at_most(p, limit)
            if len(data) > limit:
                size = p.stat().st_size
                raise InputError(f"{what} of {f'{size:,} bytes' if size > limit else 'more bytes'}: at most "
                                 f"{limit / 2**20:g} MB ({limit:,} bytes) in one {what}", str(p))
            return data
        cap = min(limit, MAX_GUNZIP_BYTES)
        with gzip.open(p, "rb") as fh:
            data = fh.read(cap + 1)
        if len(data) > cap:
            if limit <= MAX_GUNZIP_BYTES:
                raise InputError(f"{what} decompresses to more than {limit / 2**20:g} MB: at most "
                                 f"{limit / 2**20:g} MB in one {what}", str(p))
            raise ExpandsTooFar(p, cap).input_error()
        return data
    except EOFError:
        raise InputError("gzip data ends early (truncated file)", str(p)) from None
    except (gzip.BadGzipFile, zlib.error) as e:
        raise InputError(f"cannot read gzip data ({e})", str(p)) from None
    except OSError as e:
        raise InputError(f"cannot read {what} ({e.strerror or e})", str(p)) from None
