"""The pipeline: registration and classification put together, frame by frame.

- :mod:`~pcreg.pipeline.pair`: one pair of labelled frames, every method scored
  (:func:`process_pair`), and the single register-or-fall-back (:func:`register_pair`);
- :mod:`~pcreg.pipeline.temporal`: the temporal filter (:class:`TemporalFusion`);
- :mod:`~pcreg.pipeline.sequence`: a sequence walked with increment k (:func:`run_sequence`);
- :mod:`~pcreg.pipeline.stream`: a stream labelled from one key frame (:class:`Propagator`).
"""

from .pair import (DENSE_GLOBAL_MODEL, METHODS, PIPELINE_REGISTRATION, STAGES, PairArrays, PairRegistration,
                   PairResult, PipelineConfig, ProcessedPair, flow_field, log_odds, motion_of, process_pair,
                   register_pair)
from .sequence import SequenceResult, pair_indices, resolve_fusion_frames, run_sequence
from .stream import STEP_STAGES, Propagator, StepReport
from .temporal import TemporalFusion, registration_supported, temporal_update

__all__ = [
    "METHODS", "STAGES", "PIPELINE_REGISTRATION", "DENSE_GLOBAL_MODEL", "PipelineConfig", "log_odds",
    "PairRegistration", "motion_of", "register_pair", "flow_field", "PairResult", "PairArrays", "ProcessedPair",
    "process_pair", "TemporalFusion", "registration_supported", "temporal_update", "SequenceResult",
    "run_sequence", "pair_indices", "resolve_fusion_frames", "Propagator", "StepReport", "STEP_STAGES",
]
