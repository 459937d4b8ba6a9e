"""Video input: reading footage, sparse LK tracking, dense optical flow and flow PCA (OpenCV; never bpy)."""
