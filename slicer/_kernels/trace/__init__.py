"""The slicing tracer: every voxel centre of vertical rays, summed and union blends, and binning."""
