"""The one launch/retry loop of the tracer and the renderer (slicer._kernels.runtime.launch)."""
from __future__ import annotations

import numpy as np
import pytest

from slicer._kernels.runtime.launch import launch_until_fits


def test_items_are_relaunched_with_growing_room_until_they_fit():
    need = {0: 1, 1: 5, 2: 70, 3: 3}            # room each item needs
    calls, done = [], {}

    def launch(pending, scale):
        calls.append((pending.tolist(), scale))
        full = np.array([need[i] > scale for i in pending])
        done.update({int(i): scale for i, f in zip(pending, full) if not f})
        return full

    launch_until_fits(launch, np.arange(4), "test kernel")
    assert calls == [([0, 1, 2, 3], 1), ([1, 2, 3], 4), ([1, 2], 16), ([2], 64), ([2], 256)]
    assert done == {0: 1, 3: 4, 1: 16, 2: 256}


def test_a_kernel_that_never_fits_is_an_internal_error_not_a_hang():
    tries = []

    def launch(pending, scale):
        tries.append(scale)
        return np.ones(len(pending), bool)

    with pytest.raises(RuntimeError, match="the test kernel's buffers kept overflowing"):
        launch_until_fits(launch, np.arange(3), "test kernel", tries=5)
    assert tries == [1, 4, 16, 64, 256]
