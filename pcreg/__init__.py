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
    "RegistrationResult": "pcreg.result",
    "IcpIteration": "pcreg.result",
    "ImageCloud": "pcreg.clouds",
    "image_cloud": "pcreg.clouds",
    "cloud_pyramid": "pcreg.clouds",
    "load_image": "pcreg.clouds",
    "icp": "pcreg.registration",
    "register": "pcreg.registration",
    "crosscheck": "pcreg.crosschecks",
    "warp": "pcreg.warping",
    "transforms": "pcreg.transforms",
    # datasets and classification
    "Frame": "pcreg.datasets",
    "load_lagr": "pcreg.datasets",
    "load_folder": "pcreg.datasets",
    "synthetic": "pcreg.datasets",
    "NaiveBayesPixelClassifier": "pcreg.bayes",
    "relative_transform": "pcreg.datasets",
    "load_dataset": "pcreg.datasets",
    "SYNTHETIC_PRESETS": "pcreg.datasets",
    "thesis_weight_search": "pcreg.bayes",
    "error_rate": "pcreg.metrics",
    "confusion_matrix": "pcreg.metrics",
    # the registration-augmented pipeline
    "PipelineConfig": "pcreg.pipeline",
    "process_pair": "pcreg.pipeline",
    "run_sequence": "pcreg.pipeline",
    "FusionConfig": "pcreg.fusion",
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
