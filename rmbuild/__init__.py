"""rmbuild: offline graph-SLAM radio-map builder.

Walks (dead-reckoned per-step poses, each in its own unknown frame) plus Wi-Fi scans go in; one aligned
radio map comes out. See README.md and docs/ for the pipeline and the on-disk formats.
"""

__version__ = "0.1.0"
