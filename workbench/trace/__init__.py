"""Pixel-probe traces as a person reads them, shared by the viewer's inspector and the rerun stream: plots and the
candidate table (``figures``), the probed window in every source image (``windows``)."""
