"""Dense (non-rigid) registration of two images as 2-D colour clouds.

A global registration (:func:`pcreg.register`, similarity or projective) is refined into a smooth
displacement field by a non-rigid ICP, coarse to fine:

- **Clouds.** At each pyramid level the reference cloud is every pixel of the reference image, each a
  point ``(x, y, lam * colour)``; the moving cloud is every moving pixel with texture (gradient above
  the image's noise), so flat areas and edges alike carry samples, not edges alone.
- **Field.** Displacements ``U`` (M, 2) on a control grid of spacing ``grid_spacing`` (:class:`Membrane`) pixels of the
  level, interpolated bilinearly: a moving point ``p`` lands at ``G(p) + B(p) U`` (``G`` the global
  transform, ``B`` (N, M) sparse bilinear weights). This is the free-form deformation of Rueckert et
  al. (1999, "Nonrigid registration using free-form deformations", IEEE TMI 18(8)) with first-order
  (bilinear) instead of cubic B-splines. From one level to the next the grid is interpolated and its
  displacements doubled; every level keeps the same spacing in its own pixels, so the field gets finer
  as the images do.
- **Colour.** Matching uses each level's texture part (the image minus its 4-pixel Gaussian blur, with
  a twentieth of the blur kept; Wedel et al. 2009's structure-texture split), so brightness, colour
  temperature, shadows and haze that change between frames are not read as motion.
- **Correspondences.** Each moving point's nearest neighbour in ``(x, y, lam * colour)`` among the
  reference pixels within a gate of ``radius`` pixels of the level around where the field puts it
  (an exact search over the window, compiled with numba), refined to sub-pixel by a Gauss-Newton
  step on the same cost with the reference colour linearised (Park, Zhou & Koltun 2017). The gate is ``radius * 2^level`` full-resolution
  pixels: wide at the coarsest level, narrow at the finest.
- **Robust weights.** A match gets weight 0 when it has no partner: its best candidate lies on the
  window's rim (the true partner may be outside the gate: occlusion or a motion beyond the gate) or it
  is not mutual (the reference point's own nearest moving pixel, searched back, is more than a pixel
  from the point; Zhang 1994's consistency test). The others get Tukey's biweight of their colour
  distance with a scale from its median absolute deviation (Huber and Tukey robust ICP weights).
- **Step.** The grid minimises ``sum_i w_i |B_i U - t_i|^2 + alpha * sum_(a,b) |U_a - U_b|^2`` over
  the grid's 4-neighbour edges (a membrane, as the smoothness term of Horn & Schunck 1981), with
  ``t_i`` the matched reference point minus ``G(p_i)``: a sparse symmetric positive definite system
  ``(B^T W B + alpha L + eps I) U = B^T W t`` solved with ``scipy.sparse`` (conjugate gradients
  warm-started from the last field, an inexact step inside the ICP loop, or an exact LU). ``eps`` is a tiny pull
  towards the global transform, so that a grid region without any evidence keeps it.
- **Stiffness.** ``alpha`` is a ratio of variances, as in a Gaussian prior on the field (the
  Bayesian reading of the membrane): a match is good to about ``sigma_m = 1`` pixel of its level (the
  reference cloud is the pixel grid), and neighbouring nodes, ``s`` pixels apart, may differ by
  ``sigma_s = strain * s`` pixels, ``strain`` the largest plausible motion gradient (default 0.25: a
  quarter of a pixel per pixel, the parallax of a ground plane next to a facade when a car drives a
  metre forward). So ``alpha = sigma_m^2 / sigma_s^2 = 1 / (strain * s)^2`` per unit sample weight,
  independent of the image and of its content. It is multiplied by the schedule of Amberg, Romdhani
  & Vetter (2007, "Optimal Step Nonrigid ICP Algorithms for Surface Registration", CVPR): stiff
  first (8, 4, 2, then 1 for the remaining iterations of each level), so the first steps move the
  field as a whole and the last ones let it bend.
- **Colour weight.** ``lam = 1 / (sqrt(6) sigma)`` with ``sigma`` the image noise of each level
  (Immerkaer 1996, "Fast noise variance estimation", from the Laplacian): a colour difference that
  two noisy pixels of the same point show (3 channels, two noisy pixels: ``6 sigma^2``) costs as much
  as one pixel of distance.

The field is returned at full resolution as (H, W, 2) float32 reference coordinates of every moving
pixel, with a per-pixel confidence in [0, 1]: the samples' weight near each pixel (1 where a grid cell
holds as many inlier samples as a quarter of its pixels), 0 where the field leaves the reference
image. Where there is no texture the field is the smooth interpolation of its surroundings, or the
global transform, and its confidence is low.

The package, one job to a module:

- :mod:`.options`: :class:`DenseOptions`, the options, checked, with their parts :class:`Membrane` and
  :class:`GlobalStep`;
- :mod:`.result`: :class:`DenseRegistrationResult` and the callback's :class:`DenseIteration`;
- :mod:`.levels`: the pyramids (a reference's prepared once: :func:`prepare_reference`), noise, samples
  and texture of each level, and its matching problem;
- :mod:`.window`: the compiled windowed correspondence search (:func:`match_window`);
- :mod:`.robust`: Tukey's weights and their scale;
- :mod:`.grid`: the control grid, its normal equations and their solvers;
- :mod:`.coarse_to_fine`: the ICP of each level, coarse to fine (:func:`refine_field`);
- :mod:`.field`: the field and its confidence at full resolution.
"""

from __future__ import annotations

from ..motion import field_from_matrix
from .coarse_to_fine import DENSE_STAGES, InitialGrid, refine_field
from .levels import DenseReference, prepare_reference
from .options import DENSE_GLOBAL_MODEL, STIFFNESS_SCHEDULE, DenseOptions, GlobalStep, Membrane, finest_grid_shape
from .result import DenseIteration, DenseRegistrationResult
from .window import match_window

__all__ = ["DenseRegistrationResult", "DenseIteration", "refine_field", "field_from_matrix",
           "match_window", "STIFFNESS_SCHEDULE", "DENSE_STAGES", "DenseOptions", "GlobalStep", "Membrane", "DENSE_GLOBAL_MODEL",
           "InitialGrid", "finest_grid_shape", "DenseReference", "prepare_reference"]
