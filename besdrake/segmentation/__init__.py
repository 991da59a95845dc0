"""Behaviour segmentation (vMCI and baselines) and 1-NN movement classification."""

from besdrake.segmentation.base import SegmentationError, SegmentationResult
from besdrake.segmentation.vmci import VMCI, VMCIResult
from besdrake.segmentation.zvc import ZeroVelocitySegmenter

__all__ = ["VMCI", "VMCIResult", "SegmentationError", "SegmentationResult", "ZeroVelocitySegmenter"]
