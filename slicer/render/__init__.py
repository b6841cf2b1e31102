"""Transparent rendering: every crossing of every camera ray, parts included, and its outputs."""
