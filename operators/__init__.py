"""One operator per user action; thin: read settings -> core -> write -> report."""

from . import calibration, importers, mapping, neutral, solve, stabilise, tuning, video

CLASSES = (importers.CLASSES + stabilise.CLASSES + neutral.CLASSES + solve.CLASSES + calibration.CLASSES
           + mapping.CLASSES + video.CLASSES + tuning.CLASSES)
