"""pcreg's compiled kernels (numba, cached on disk), compiled all at once so that no command pauses for it.

    python -m pcreg.registration.kernels      # what `make setup` runs after installing

The kernels: the exact correspondence search (:mod:`.nn`), the reference ICP's point-to-point loop
(:mod:`.reference`), the sub-pixel edges of the image pyramids (:mod:`.clouds`), the dense
registration's window search, assembly and solver (:mod:`.dense`) and the field of a transform
(:mod:`.motion`).
"""

from __future__ import annotations

import os
import time

import numpy as np


def warm_up() -> None:
    """Compile (or load from the on-disk cache) every compiled kernel of pcreg, on small inputs."""
    from . import nn, reference
    from .clouds import image_pyramid
    from .api import register_dense

    nn.warm_up()
    reference.warm_up()
    img = np.zeros((64, 64, 3), np.uint8)
    img[16:48, 20:40] = 200
    image_pyramid(img, levels=2).clouds(max_points=100)
    a, b = _textured_pair()
    register_dense(a, b)


def _textured_pair(size: int = 96, shift: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Two (size, size, 3) uint8 views of one smooth random texture, ``shift`` px apart: enough texture
    at every level for the dense registration's kernels to run."""
    import cv2

    rng = np.random.default_rng(0)
    cells = rng.integers(0, 256, (size // 4 + shift, size // 4 + shift, 3), dtype=np.uint8)
    texture = cv2.resize(cells, ((size + 4 * shift),) * 2, interpolation=cv2.INTER_CUBIC)
    return (np.ascontiguousarray(texture[:size, :size]),
            np.ascontiguousarray(texture[shift:size + shift, shift:size + shift]))


def main() -> int:  # pragma: no cover - run by the Makefile
    t0 = time.perf_counter()
    warm_up()
    print(f"pcreg: compiled kernels ready in {time.perf_counter() - t0:.1f} s "
          f"(cache: {os.path.dirname(__file__)}/__pycache__ or NUMBA_CACHE_DIR)")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
