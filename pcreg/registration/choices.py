"""The names an ICP's options choose among, and which motion models Open3D's ICP fits: the lowest room
of the registration's options, so that the configurations (:mod:`~pcreg.registration.config`,
:mod:`~pcreg.registration.icp_options`) and the ICPs (:mod:`~pcreg.registration.reference`,
:mod:`~pcreg.registration.open3d_icp`) take them from one place and not from each other."""

from __future__ import annotations

from ..errors import InputError

__all__ = ["BACKENDS", "WEIGHTS", "METRICS", "ROTATIONS", "OPEN3D_MODELS", "check_open3d_model"]

#: The ICP backends (the ICP steps of :data:`pcreg.registration.steps.ICP_STEPS`, in that order).
BACKENDS = ("reference", "open3d")
#: Robust weights of the reference backend's steps.
WEIGHTS = ("none", "trimmed", "huber", "tukey")
#: Distances minimised: point to point, or (2-D, reference backend) point to the target's tangent line.
METRICS = ("point_to_point", "point_to_line", "point_to_plane")
#: The 3-D rigid closed form of the reference backend: Umeyama's SVD or Horn's quaternion.
ROTATIONS = ("svd", "quaternion")
#: The motion models Open3D's point-to-point estimation fits.
OPEN3D_MODELS = ("rigid", "similarity")


def check_open3d_model(model: str) -> None:
    """Raise :class:`InputError` for a motion model Open3D's point-to-point estimation cannot fit."""
    if model not in OPEN3D_MODELS:
        raise InputError(
            f"the open3d backend (point-to-point) supports the {' and '.join(OPEN3D_MODELS)} models, not {model!r}; "
            "use backend='reference' (--backend reference)"
        )
