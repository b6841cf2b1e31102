"""The model: the skeleton of tapered segments, the SIIS kernel's parameters, blends and the field API."""
