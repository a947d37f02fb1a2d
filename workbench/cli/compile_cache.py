"""Fill numba's on-disk cache in a process of its own: ``python -m workbench.cli.compile_cache``.

Why a separate process: numba code compiled in the running process and the same code loaded from its
cache by a later process do not round identically (numba/numba#10617 sees the two optimised
differently; here the float32 fast-math NCC kernels). PatchMatch amplifies last-bit differences into
different maps (same quality: tiny within 1 % moves by about 0.03 points), so the first run after an
install would not reproduce later runs with the same seed. Compiling once here, before any real run,
means every run (the demo, the tests, ``deepc regress``) loads the same cached machine code.
scripts/setup.sh calls this; it is quick when the cache is already valid.
"""

from __future__ import annotations

import sys
import time

from workbench.regress import DEFAULT_SUITE, load_suite, warm_up


def main() -> int:
    start = time.perf_counter()
    warm_up(load_suite(DEFAULT_SUITE).runs)
    print(f"numba cache ready ({time.perf_counter() - start:.1f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
