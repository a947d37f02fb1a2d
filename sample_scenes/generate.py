"""Regenerate the committed sample scenes deterministically.

    python sample_scenes/generate.py [--only tiny|small] [--out-root DIR]

``tiny`` (5 views, 160x120, text COLMAP model) is for unit tests; ``small`` (8 views, 320x240,
binary model) for the demo and regression runs. Both are written in the scene layout that
``engine.scene.load_scene`` reads, replacing any earlier copy atomically.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # run as a script from anywhere, without installing the package
    sys.path.insert(0, str(ROOT))

from engine.synthetic import small_scene, tiny_scene, write_scene  # noqa: E402

SCENES = {"tiny": (tiny_scene, False), "small": (small_scene, True)}  # name: (recipe, binary model)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", choices=sorted(SCENES), help="generate only this scene")
    parser.add_argument("--out-root", type=Path, default=Path(__file__).resolve().parent,
                        help="folder that receives tiny/ and small/ (default: sample_scenes/)")
    args = parser.parse_args(argv)
    for name in [args.only] if args.only else list(SCENES):
        recipe, binary = SCENES[name]
        start = time.perf_counter()
        data = write_scene(recipe(), args.out_root / name, binary_model=binary,
                           command=f"python sample_scenes/generate.py --only {name}")
        print(f"{name}: {len(data.images)} views {data.cameras[0].width}x{data.cameras[0].height}, "
              f"{data.sparse.num_points} sparse points, GT coverage {100 * data.coverage():.1f}%, "
              f"{len(data.gt_points)} GT points -> {args.out_root / name} ({time.perf_counter() - start:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
