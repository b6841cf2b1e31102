"""The SIIS field in compiled code: one segment in closed form, eight at a time, at points, union."""
