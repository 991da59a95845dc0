"""Behaviour segmentation (vMCI and baselines) and 1-NN movement classification.

* :class:`VMCI`: velocity-based multiple changepoint inference (Senger et al. 2014 on
  Fearnhead & Liu 2007), ``VMCI().fit(recording).segments_``.
* :class:`ZeroVelocitySegmenter`: the zero-velocity-crossing baseline.
* :class:`BorderRules`: border placement conventions applied after vMCI
  (``VMCI(rules=...)``), learned on a labelled subject by :func:`tune_vmci`.
* :class:`SegmentClassifier`: 1-NN classifier of segments (``fit(segments, labels)``, ``predict``).
* :mod:`besdrake.segmentation.evaluation`: border scoring and labelled-folder loading.
* :mod:`besdrake.segmentation.conventions`: how an annotator places borders (pauses, speed
  levels, distance from speed minima), to compare two annotators before tuning on one.
"""

from besdrake.segmentation.base import SegmentationError, SegmentationResult
from besdrake.segmentation.classification import (
    ClassificationError,
    MovementSegment,
    SegmentClassifier,
    SegmentFeatures,
    extract_segment,
)
from besdrake.segmentation.placement import BorderRules, apply_rules, learn_rules
from besdrake.segmentation.tuning import TunedVMCI, tune_vmci
from besdrake.segmentation.vmci import VMCI, VMCIResult
from besdrake.segmentation.zvc import ZeroVelocitySegmenter

__all__ = [
    "BorderRules",
    "TunedVMCI",
    "VMCI",
    "VMCIResult",
    "ClassificationError",
    "MovementSegment",
    "SegmentClassifier",
    "SegmentFeatures",
    "SegmentationError",
    "SegmentationResult",
    "ZeroVelocitySegmenter",
    "apply_rules",
    "extract_segment",
    "learn_rules",
    "tune_vmci",
]
