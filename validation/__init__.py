"""Validation: meshed references, metrics, benchmarks and stiff cases."""
