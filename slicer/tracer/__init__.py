"""The tracer: the voxel grid, per-bucket primitive lists and the ray walk's API (inside runs per column)."""
