"""The transparent renderer: every crossing of every camera ray, and their compositing."""
