"""The GTSAM pose graph of `rmbuild optimize` (the only package that imports gtsam).

Public entry point: :func:`optimize` (pure, in-memory) returning an :class:`OptimizeResult`. Both are
loaded on first use: importing a submodule (e.g. :mod:`rmbuild.slam.held`) does not import the
full pipeline and the modules only it needs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rmbuild.slam.pipeline import optimize
    from rmbuild.slam.result import OptimizeResult

__all__ = ["OptimizeResult", "optimize"]


def __getattr__(name: str) -> Any:
    if name == "optimize":
        from rmbuild.slam.pipeline import optimize

        return optimize
    if name == "OptimizeResult":
        from rmbuild.slam.result import OptimizeResult

        return OptimizeResult
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
