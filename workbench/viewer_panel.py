"""The viewer's control panel: every control with its initial value, and the ViewParams the controls describe.

:class:`ControlPanel` is the base of :class:`workbench.viewer.ViewerApp`: it declares the controls as
attributes of the app (``app.pipeline``, ``app.conf_tau``, ``app.preset``, ...) and wires their events to
what the app does with them (``request``, ``_recolor_latest``, ``_set_point_size``, ``export_ply``,
``save_rrd``, ``select_view``). The fusion preset dropdown and the fusion sliders follow each other.
"""

from __future__ import annotations

import math
from typing import Any

import viser

from engine.fusion import FUSION_PRESETS, FusionOptions
from workbench.map_images import subsample
from workbench.session import COLOR_MODES, ViewerSession, ViewParams

CUSTOM = "custom"  # the fusion preset dropdown's entry for slider values no preset has
PANEL_IMAGE = 320  # longest side of the view images in the side panel

# The FusionOptions fields the Fusion panel controls, each with the type its widget's value converts to.
FUSION_CONTROLS = {"max_reproj_error": float, "max_depth_error": float, "max_normal_error": float,
                   "min_num_pixels": int, "point_per_pixel": bool}


def preset_of(fusion: FusionOptions) -> str:
    """Name of the preset whose controlled fields (``FUSION_CONTROLS``) ``fusion`` has, else ``CUSTOM``."""
    for name in sorted(FUSION_PRESETS):
        p = FUSION_PRESETS[name]
        if all(math.isclose(getattr(p, field), getattr(fusion, field), abs_tol=1e-9) for field in FUSION_CONTROLS):
            return name
    return CUSTOM


class ControlPanel:
    """The GUI of a viewer app; subclasses provide ``server``, ``session``, ``default_point_size`` and the
    handlers named in the module docstring."""

    server: viser.ViserServer
    session: ViewerSession
    default_point_size: float

    def _build_gui(self) -> None:
        gui = self.server.gui
        s = self.session
        defaults = ViewParams()
        gui.add_markdown(f"**DeepC Workbench** · {s.scene.name} · {len(s.scene.views)} views")
        with gui.add_folder("Pipeline"):
            self.pipeline = gui.add_dropdown("Pipeline", options=tuple(s.pipelines or ["vanilla"]),
                                             initial_value=(s.pipelines or ["vanilla"])[0],
                                             disabled=len(s.pipelines) <= 1)
            self.conf_tau = gui.add_slider("Confidence τ", min=0.0, max=1.0, step=0.01,
                                           initial_value=defaults.conf_tau, disabled=not s.has_confidence,
                                           hint="keep pixels with confidence ≥ τ (fast and full pipelines)")
            self.mask_k = gui.add_slider("Mask k", min=0, max=10, step=1, initial_value=0,
                                         disabled=not s.has_counter,
                                         hint="keep pixels with ≥ k consistent source views (0 = off)")
        with gui.add_folder("Fusion"):
            f = defaults.fusion
            self.preset = gui.add_dropdown("Preset", options=(*sorted(FUSION_PRESETS), CUSTOM),
                                           initial_value=preset_of(f),
                                           hint="named thresholds (pixels = what deepc run fuses with; dense = "
                                                "one median point per cluster, lighter to tune; deepc = the "
                                                "paper's); moving a control makes it custom")
            self.reproj = gui.add_slider("Reprojection error (px)", min=0.25, max=4.0, step=0.25,
                                         initial_value=f.max_reproj_error)
            self.depth_err = gui.add_slider("Depth error (rel.)", min=0.001, max=0.05, step=0.001,
                                            initial_value=f.max_depth_error)
            self.normal_err = gui.add_slider("Normal angle (°)", min=1.0, max=90.0, step=1.0,
                                             initial_value=f.max_normal_error)
            self.min_views = gui.add_slider("Min views", min=1, max=10, step=1, initial_value=f.min_num_pixels,
                                            hint="fewest fused pixels per point, the seed included")
            self.per_pixel = gui.add_checkbox("Point per pixel", initial_value=f.point_per_pixel,
                                              hint="every pixel of a kept cluster is a point (else the cluster's "
                                                   "median is one point)")
            self._fusion_handles = dict(zip(FUSION_CONTROLS, (self.reproj, self.depth_err, self.normal_err,
                                                              self.min_views, self.per_pixel), strict=True))
        with gui.add_folder("Display"):
            self.point_size = gui.add_slider("Point size", min=self.default_point_size / 10,
                                             max=self.default_point_size * 10, step=self.default_point_size / 10,
                                             initial_value=self.default_point_size)
            self.color_mode = gui.add_dropdown("Colour", options=COLOR_MODES, initial_value="rgb")
        with gui.add_folder("Metrics"):
            self.metrics = gui.add_markdown("computing…" if s.has_maps else
                                            "no maps: run `deepc run` and open its output folder")
        with gui.add_folder("Export"):
            self.export_name = gui.add_text("File name", initial_value="cloud")
            self.export_button = gui.add_button("Export cloud (PLY)", disabled=not s.has_maps)
            self.rrd_button = gui.add_button("Save state (.rrd)", disabled=not s.has_maps)
            self.export_status = gui.add_markdown("")
        with gui.add_folder("View"):
            self.view_title = gui.add_markdown("")
            self.view_images: dict[str, Any] = {}
            for kind, image in s.view_images(0).items():
                self.view_images[kind] = gui.add_image(subsample(image, PANEL_IMAGE), label=kind, format="jpeg")
        self.select_view(0)

        self._applying_preset = False
        for handle in (self.pipeline, self.conf_tau, self.mask_k):
            handle.on_update(lambda _event: self.request(self.params()))
        for handle in self._fusion_handles.values():
            handle.on_update(lambda _event: self._fusion_slider_moved())
        self.preset.on_update(lambda _event: self._apply_preset())
        self.color_mode.on_update(lambda _event: self._recolor_latest())
        self.point_size.on_update(lambda _event: self._set_point_size())
        self.export_button.on_click(lambda _event: self.export_ply())
        self.rrd_button.on_click(lambda _event: self.save_rrd())

    def _apply_preset(self) -> None:
        """Set the fusion controls to the chosen preset; one recomputation, not five."""
        if self._applying_preset or self.preset.value == CUSTOM:
            return
        f = FUSION_PRESETS[str(self.preset.value)]
        self._applying_preset = True
        try:
            for field, handle in self._fusion_handles.items():
                handle.value = getattr(f, field)
        finally:
            self._applying_preset = False
        self.request(self.params())

    def _fusion_slider_moved(self) -> None:
        if self._applying_preset:
            return
        name = preset_of(self.params().fusion)
        if self.preset.value != name:
            self._applying_preset = True  # the dropdown only names the sliders' state here
            try:
                self.preset.value = name
            finally:
                self._applying_preset = False
        self.request(self.params())

    def params(self) -> ViewParams:
        """The ViewParams the controls describe now."""
        fusion = ViewParams().fusion.replace(**{field: FUSION_CONTROLS[field](handle.value)
                                                for field, handle in self._fusion_handles.items()})
        return ViewParams(pipeline=str(self.pipeline.value), conf_tau=float(self.conf_tau.value),
                          mask_k=int(self.mask_k.value), fusion=fusion)
