"""The headless front end: one take from a config (``python -m facecap retarget``), the demo, what the
command line prints, and the .blend files a run opens and writes."""
