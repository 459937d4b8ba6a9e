"""Scene adapters: marker empties, shape-key and action keying, the solve layer, binding, tuning and video
data moved between the scene and numpy."""
