"""Input formats. Each module registers one reader; the list below is the explicit registry."""

from __future__ import annotations

import importlib
from pathlib import Path

from rmbuild.errors import InputError
from rmbuild.io.formats.base import REGISTRY, RawInput, Reader, register

#: modules that define readers (imported once, in this order; sniffing tries them in this order)
_MODULES = ("rmbuild_schema", "msft_ilc", "ipin")
_loaded = False


def _load() -> None:
    global _loaded
    if not _loaded:
        for m in _MODULES:
            importlib.import_module(f"rmbuild.io.formats.{m}")
        _loaded = True


def reader_names() -> list[str]:
    _load()
    return list(REGISTRY)


def expand_inputs(paths: list[str | Path]) -> list[Path]:
    """Regular files named by ``paths``; directories are walked recursively (hidden files skipped)."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out.extend(sorted(f for f in p.rglob("*") if f.is_file() and not any(
                part.startswith(".") for part in f.relative_to(p).parts)))
        elif p.is_file():
            out.append(p)
        elif p.exists():
            raise InputError("not a regular file or directory", str(p))
        else:
            raise InputError("no such file or directory", str(p))
    if not out:
        raise InputError("no input files found", ", ".join(map(str, paths)) or "(none)")
    return out


def choose_reader(files: list[Path], fmt: str | None) -> Reader:
    """The reader named ``fmt``, or the first registered reader whose ``sniff`` accepts ``files``."""
    _load()
    if fmt is not None:
        if fmt not in REGISTRY:
            raise InputError(f"unknown format {fmt!r} (known: {', '.join(REGISTRY)})")
        return REGISTRY[fmt]()
    for cls in REGISTRY.values():
        if cls.sniff(files):
            return cls()
    raise InputError(
        f"could not recognise the input format of {files[0]} (and {len(files) - 1} other files); "
        f"pass --format (known: {', '.join(REGISTRY)})"
    )


__all__ = ["REGISTRY", "RawInput", "Reader", "choose_reader", "expand_inputs", "reader_names", "register"]
