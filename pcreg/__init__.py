"""pcreg: register images as 2-D/colour point clouds, then label images and video per pixel.

The public API is the names in ``__all__``: what a user of the three uses (register, label a stream,
cross-check) needs. Everything else is importable from its sub-package (``pcreg.registration``,
``pcreg.datasets``, ``pcreg.classification``, ``pcreg.pipeline``, ...), documented there. Names are imported on first
use so that ``import pcreg`` stays cheap (Open3D, rerun and scikit-learn load only when needed).
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.3.0.dev0"

_EXPORTS = {
    # registration: images and clouds
    "register": "pcreg.registration.api",
    "register_dense": "pcreg.registration.api",
    "DenseOptions": "pcreg.registration.dense",
    "RegisterConfig": "pcreg.registration.config",
    "RegistrationResult": "pcreg.registration.result",
    "icp": "pcreg.registration.api",
    "ICPOptions": "pcreg.registration.icp_options",
    "VoxelSchedule": "pcreg.registration.icp_options",
    "image_cloud": "pcreg.registration.clouds",
    "load_image": "pcreg.registration.clouds",
    "load_image_and_mask": "pcreg.registration.clouds",
    "warp": "pcreg.registration.warp",
    "transforms": "pcreg.registration.transforms",
    "crosscheck": "pcreg.implementations.crosscheck",
    # data and classification
    "Frame": "pcreg.datasets",
    "load_dataset": "pcreg.datasets",
    "synthetic": "pcreg.datasets",
    "fit_classifier": "pcreg.classification.bayes",
    "error_rate": "pcreg.classification.metrics",
    # labelling a stream from a key frame
    "Propagator": "pcreg.pipeline.stream",
    "PreparedFrame": "pcreg.frame",
    # errors
    "PcregError": "pcreg.errors",
    "InputError": "pcreg.errors",
    "RegistrationError": "pcreg.errors",
}

_MODULES = {"transforms"}  # exported as modules; every other name is an attribute of its module

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'pcreg' has no attribute {name!r}")
    # not kept in the module's globals: sys.modules holds the imported module, and the name is looked
    # up there on each use
    mod = importlib.import_module(module)
    return mod if name in _MODULES else getattr(mod, name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
