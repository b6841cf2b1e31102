"""Raster layers: exact pixel coverage of polygons, connected components, counting sorts."""
