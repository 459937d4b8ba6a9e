"""The sidebar: the FaceCap tab's panels and the settings they show (``Scene.facecap``)."""
