"""Scenes in and out: the JSON scene format, OBJ polylines, 3MF input, and the lattice generator."""
