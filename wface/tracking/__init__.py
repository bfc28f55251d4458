"""Tracking: muscle activations and cranium/jaw motion from motion-capture markers (seed 000)."""

from wface.tracking.estimator import FrameEstimator, FrameResult, MarkerMap, TrackOptions

__all__ = ["FrameEstimator", "FrameResult", "MarkerMap", "TrackOptions"]
