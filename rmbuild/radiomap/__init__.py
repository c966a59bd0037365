"""Radio map: rasterise map nodes' fingerprints onto a grid, RSS histograms by walking direction, optional
fill, tables and figures; the reference points localizers match against."""

from rmbuild.radiomap.build import RadioMap, build_radio_map, grid_origin
from rmbuild.radiomap.histogram import HistogramLayer
from rmbuild.radiomap.reference import ReferenceSet

__all__ = ["HistogramLayer", "RadioMap", "ReferenceSet", "build_radio_map", "grid_origin"]
