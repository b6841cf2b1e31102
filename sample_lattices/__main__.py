"""``python -m sample_lattices [NAME ...]``: regenerate the committed sample scenes."""
from __future__ import annotations

import sys

from slicer.errors import SceneError

from . import load_sample, write_samples


def main(argv: list[str]) -> int:
    try:
        paths = write_samples(argv or None)
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for path in paths:
        skel = load_sample(path.stem)
        lo, hi = skel.nodes.min(axis=0), skel.nodes.max(axis=0)
        print(f"{path.name}: {skel.n_nodes} nodes, {skel.n_segments} segments, "
              f"bbox {lo.round(3).tolist()}..{hi.round(3).tolist()} mm, "
              f"radius {skel.radii.min():g}..{skel.radii.max():g} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
