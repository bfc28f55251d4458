"""Tracking: muscle activations and cranium/jaw motion from motion-capture markers (Sifakis et al. 2005)."""

from wface.tracking.estimator import FrameEstimator, FrameResult, TrackOptions
from wface.tracking.markers import MarkerMap

__all__ = ["FrameEstimator", "FrameResult", "MarkerMap", "TrackOptions"]
