"""The cross-character realism benchmark (``python -m facecap bench --realism``): a real human face model
(ICT-FaceKit, read from the shared data, never shipped) with perturbed expressions, driven by real iPhone
performances, captured with studio layouts, solved onto characters of other styles and compared with the
performance's own weights per face region (``bench``)."""
