"""One operator per user action; thin: read settings -> core -> write -> report."""

from . import markers, neutral, solve, stabilise

CLASSES = markers.CLASSES + stabilise.CLASSES + neutral.CLASSES + solve.CLASSES
