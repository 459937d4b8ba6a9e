"""The character's side: its shapes sampled at the bound points (``Basis``), per-shape solve options
(bounds, locks, regions) and controls (gain, offset, curve), shape-name aliases, conditioning
diagnostics and the camera that projects it into footage."""
