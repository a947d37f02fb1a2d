"""The viser viewer: the app (``app``), live during a run (``live``), the declared GUI panel (``panel``), legends and
histograms (``legends``), meshes (``mesh``), exports (``export``), the pixel inspector (``inspector``), the stage
caches of a session without viser (``session``) and newest-request-wins recomputation (``scheduler``)."""
