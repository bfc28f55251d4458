"""Speech: the ArtiSynth speech gestures (excitation curves) played on a face model.

Modules: ``gestures`` (read ArtiSynth probe files and map their exciters onto a model's muscles),
``playback`` (frames of quasistatic equilibria, lip opening, capture-marker selection and
performance playback for the Badin face), ``output`` (the lip-opening curve and the USD stage).
"""

from wface.speech.gestures import map_gesture_to_model, read_gesture
from wface.speech.output import write_gesture_usd, write_lip_opening
from wface.speech.playback import GestureResult, lip_opening_mm, simulate_gesture, summarize

__all__ = [
    "GestureResult",
    "lip_opening_mm",
    "map_gesture_to_model",
    "read_gesture",
    "simulate_gesture",
    "summarize",
    "write_gesture_usd",
    "write_lip_opening",
]
