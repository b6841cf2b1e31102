"""Compiled helpers of the output formats: GOO run-length decoding, NanoDLP island statistics."""
