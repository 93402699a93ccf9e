"""pcreg: register images as 2-D/colour point clouds, then classify terrain per pixel.

The public API is the names in ``__all__``; everything else may change. Names are imported on first
use so that ``import pcreg`` stays cheap (Open3D, rerun and scikit-learn load only when needed).
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    # registration core
    "RegistrationResult": "pcreg.registration.result",
    "IcpIteration": "pcreg.registration.result",
    "ImageCloud": "pcreg.registration.clouds",
    "image_cloud": "pcreg.registration.clouds",
    "cloud_pyramid": "pcreg.registration.clouds",
    "image_pyramid": "pcreg.registration.clouds",
    "ImagePyramid": "pcreg.registration.clouds",
    "load_image": "pcreg.registration.clouds",
    "icp": "pcreg.registration.api",
    "register": "pcreg.registration.api",
    "register_dense": "pcreg.registration.dense",
    "DenseRegistrationResult": "pcreg.registration.dense",
    "crosscheck": "pcreg.implementations.crosscheck",
    "warp": "pcreg.registration.warp",
    "warp_to_moving": "pcreg.registration.warp",
    "transforms": "pcreg.registration.transforms",
    # datasets and classification
    "Frame": "pcreg.datasets",
    "load_lagr": "pcreg.datasets",
    "load_folder": "pcreg.datasets",
    "synthetic": "pcreg.datasets",
    "NaiveBayesPixelClassifier": "pcreg.classification.bayes",
    "relative_transform": "pcreg.datasets",
    "load_dataset": "pcreg.datasets",
    "SYNTHETIC_PRESETS": "pcreg.datasets",
    "thesis_weight_search": "pcreg.classification.bayes",
    "fit_classifier": "pcreg.classification.bayes",
    "error_rate": "pcreg.classification.metrics",
    "confusion_matrix": "pcreg.classification.metrics",
    # the registration-augmented pipeline
    "RegisterConfig": "pcreg.registration.config",
    "PipelineConfig": "pcreg.pipeline",
    "process_pair": "pcreg.pipeline",
    "run_sequence": "pcreg.pipeline",
    "Propagator": "pcreg.pipeline.stream",
    "FusionConfig": "pcreg.classification.fusion",
    # errors
    "PcregError": "pcreg.errors",
    "InputError": "pcreg.errors",
    "RegistrationError": "pcreg.errors",
    "DatasetError": "pcreg.errors",
    "OutputError": "pcreg.errors",
}

_MODULES = {"transforms"}  # exported as modules; every other name is an attribute of its module

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'pcreg' has no attribute {name!r}")
    mod = importlib.import_module(module)
    value = mod if name in _MODULES else getattr(mod, name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
