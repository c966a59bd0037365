"""The GTSAM pose graph of `rmbuild optimize` (the only package that imports gtsam).

Public entry point: :func:`optimize` (pure, in-memory) returning an :class:`OptimizeResult`.
"""

from rmbuild.slam.pipeline import OptimizeResult, optimize

__all__ = ["OptimizeResult", "optimize"]
