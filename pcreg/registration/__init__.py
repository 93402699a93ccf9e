"""Registration of images and point clouds.

- :mod:`.clouds`: images to 2-D/colour point clouds and pyramids of them;
- :mod:`.reference`: pcreg's reference ICP (Besl & McKay; Umeyama/Horn closed forms);
- :mod:`.open3d_icp`: Open3D's point-to-point ICP on clouds lifted to z = 0;
- :mod:`.icp_options`: :class:`~.icp_options.ICPOptions`, one ICP's options (``icp`` and each backend's ICP);
- :mod:`.inputs`: the checks of the clouds and initial guesses that enter ``icp`` and each backend's ICP;
- :mod:`.global_search`: hypotheses for images (edge FFT search, Fourier-Mellin, ORB + RANSAC) and the
  evidence that tells a true alignment from chance;
- :mod:`.api`: ``icp`` (clouds), ``register`` (images: hypotheses, ICP, plausibility test) and
  ``register_dense`` (``register``'s global result refined into a dense field), made of :mod:`.steps`
  (each backend's ICP step), :mod:`.pyramid` (lazy cloud pyramids), :mod:`.refine` (coarse-to-fine ICP),
  :mod:`.search` (hypotheses, refined and measured), :mod:`.plausibility` and :mod:`.dense`;
- :mod:`.dense`: the dense field, a non-rigid ICP of the two colour clouds from a global ``T_ref_mov``
  (a package: options, result, levels, window search, robust weights, grid solver, coarse-to-fine driver, field);
- :mod:`.flow`: OpenCV's DIS optical flow as a field (the baseline of the evaluations);
- :mod:`.config`: :class:`~.config.RegisterConfig`, ``register``'s options as one frozen config, by step;
- :mod:`.motion`: :class:`~.motion.Motion`, the one motion type (a 3x3 ``T_ref_mov``, or a dense field
  with its confidence) that warping, the fusion's prior, the temporal filter and the stream take;
- :mod:`.warp`, :mod:`.transforms`, :mod:`.result`: warping, homogeneous transforms, result types.
"""
