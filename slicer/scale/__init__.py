"""Jobs larger than memory: tile plans under a budget, tile tasks, executors and ordered maps."""
