"""Radio map: rasterise map nodes' fingerprints onto a grid, optional fill, tables and figures."""

from rmbuild.radiomap.build import RadioMap, build_radio_map, grid_origin

__all__ = ["RadioMap", "build_radio_map", "grid_origin"]
