"""The viewer's control panel: every control with its initial value, and the ViewParams the controls describe.

:class:`ControlPanel` is the base of :class:`workbench.viewer.app.ViewerApp`: it declares the controls as
attributes of the app (``app.pipeline``, ``app.fused_confidence_tau``, ``app.preset``, ...) and wires their events to
what the app does with them (``request``, ``_recolor_latest``, ``_set_point_size``, ``export_ply``,
``save_rrd``, ``select_view``). The fusion preset dropdown and the fusion sliders follow each other.
The panel opens on the run's own settings (``ViewerSession.run_params``) and can go back to them; a control
that cannot act is disabled and says why, and colour modes without their data are left out with the reason.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import viser

from engine.core.words import plural
from engine.fusion import FUSION_PRESETS, FusionOptions
from workbench.maps.images import subsample
from workbench.viewer.session import COLOR_MODES, ViewerSession, ViewParams

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


def run_label(params: ViewParams, has_run: bool, sky_filter: bool = False) -> str:
    """The settings a run used, in one line: "run: fast · pixels · confidence.tau 0.1"."""
    parts = [params.pipeline, preset_of(params.fusion)]
    if params.pipeline != "vanilla":
        parts.append(f"{ViewerSession.threshold_label(params.pipeline)} {params.fused_confidence_tau:g}")
    if params.mask_k:
        parts.append(f"mask k {params.mask_k}")
    if params.pipeline == "full" and sky_filter:
        parts.append("sky filter")
    return ("run: " if has_run else "no run: defaults · ") + " · ".join(parts)


def tau_label(pipeline: str) -> str:
    """The confidence slider's label: the option it moves under ``pipeline`` (vanilla: none, the slider is off)."""
    return ViewerSession.threshold_label(pipeline) or "confidence threshold (off)"


def view_label(index: int, name: str) -> str:
    return f"{index}: {name}"


@dataclasses.dataclass(frozen=True)
class SizeSlider:
    """The point size slider in a unit that puts the default between 1 and 1000 (model units are metres, as
    the evaluation's cm tolerances take them): round ends and steps instead of 0.001222 … 0.122166."""

    unit: str
    per_metre: float  # slider value of one model unit
    min: float
    max: float
    step: float
    initial: float

    @classmethod
    def around(cls, default: float) -> SizeSlider:
        """A tenth of ``default`` (model units) to ten times it, in steps of about a tenth of it."""
        unit, per_metre = next(((u, f) for u, f in (("m", 1.0), ("cm", 100.0)) if default * f >= 1), ("mm", 1000.0))
        value = default * per_metre
        step = 10.0 ** math.floor(math.log10(value / 10)) if value > 0 else 0.1
        digits = max(0, -math.floor(math.log10(step)))
        return cls(unit, per_metre, round(step, digits), round(value * 10, digits), round(step, digits),
                   max(round(value, digits), round(step, digits)))


class ControlPanel:
    """The GUI of a viewer app; subclasses provide ``server``, ``session``, ``default_point_size`` and the
    handlers named in the module docstring."""

    server: viser.ViserServer
    session: ViewerSession
    default_point_size: float
    point_budget_default: int  # the Point budget control's initial value (app.POINT_BUDGET)
    point_budget_min: int  # ...and its minimum (app.MIN_POINT_BUDGET)

    def _build_gui(self) -> None:
        gui = self.server.gui
        s = self.session
        self.run_params = s.run_params()
        start = self.run_params
        self._base_fusion = start.fusion  # the fields the panel does not control keep the run's values
        self._last_tau = start.fused_confidence_tau
        modes = s.color_modes()
        gui.add_markdown(f"**DeepC Workbench** · {s.scene.name} · {plural(len(s.scene.views), 'view')}")
        self.run_text = gui.add_markdown(f"**{run_label(start, s.run is not None, s.sky_filter)}**" if s.has_maps
                                         else "**no run:** a COLMAP workspace, its sparse points only")
        self.reset_button = gui.add_button("Reset to the run's settings", disabled=s.run is None,
                                           hint="pipeline, confidence threshold, mask k and fusion thresholds as the "
                                                "run used them")
        with gui.add_folder("Pipeline"):
            pipelines = tuple(s.pipelines or ["vanilla"])
            self.pipeline = gui.add_dropdown("Pipeline", options=pipelines, initial_value=start.pipeline,
                                             disabled=len(pipelines) <= 1, hint=self._pipeline_reason())
            self.fused_confidence_tau = gui.add_slider(tau_label(start.pipeline), min=0.0, max=1.0, step=0.01,
                                                       initial_value=start.fused_confidence_tau,
                                                       disabled=start.pipeline == "vanilla" or not s.has_confidence,
                                                       hint="keep pixels whose confidence is at least this: "
                                                            "confidence.tau under fast, refinement."
                                                            "refined_confidence_tau (network 2's) under full")
            # k counts consistent source views: a k above a view's number of sources removes every pixel
            sources = max((len(v.source_views) for v in s.scene.views), default=1)
            self.mask_k = gui.add_slider("Mask k", min=0, max=max(1, sources), step=1,
                                         initial_value=min(start.mask_k, max(1, sources)),
                                         disabled=not s.has_counter,
                                         hint="keep pixels with ≥ k consistent source views (0 = off)")
            self.control_notes = gui.add_markdown(self._control_notes(start.pipeline))
            self.histograms = gui.add_html("".join(s.histograms(start)))
        with gui.add_folder("Fusion"):
            f = start.fusion
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
            size = self.size_slider = SizeSlider.around(self.default_point_size)
            self.point_size = gui.add_slider(f"Point size ({size.unit})", min=size.min, max=size.max, step=size.step,
                                             initial_value=size.initial,
                                             hint="diameter of a point in the scene; the default is about one "
                                                  "pixel's footprint at a typical depth")
            available = tuple(mode for mode in COLOR_MODES if not modes[mode])
            self.color_mode = gui.add_dropdown("Colour", options=available, initial_value="rgb",
                                               hint="; ".join(f"{m}: {r}" for m, r in modes.items() if r) or None)
            self.color_legend = gui.add_html(s.cloud_legend("rgb"))
            self.color_notes = gui.add_markdown("  \n".join(f"*{m}* {r}" for m, r in modes.items() if r))
            self.point_budget = gui.add_number("Point budget (points)", initial_value=self.point_budget_default,
                                               min=self.point_budget_min, max=10_000_000, step=1_000,
                                               hint="most points sent to the browser; above it the cloud is "
                                                    "thinned to one point per voxel; default from "
                                                    "docs/decisions.md (software WebGL)")
            self.budget_note = gui.add_markdown("")
        with gui.add_folder("Metrics"):
            self.metrics = gui.add_markdown("computing…" if s.has_maps else
                                            "no maps: run `deepc run` and open its output folder")
            self.metrics_table = gui.add_html("")
            self.mesh_metrics = gui.add_markdown("")  # the mesh's own scores (workbench/viewer/mesh.py)
        with gui.add_folder("View"):
            names = tuple(view_label(v.index, v.name) for v in s.scene.views)
            self.view_dropdown = gui.add_dropdown("View", options=names, initial_value=names[0])
            self.prev_button = gui.add_button("◀ previous view")
            self.next_button = gui.add_button("next view ▶")
            self.view_title = gui.add_markdown("")
            self.view_metrics = gui.add_markdown("")
            self.view_images: dict[str, Any] = {}
            self.view_legends: dict[str, Any] = {}
            full = dataclasses.replace(start, pipeline="full") if "full" in s.pipelines else start
            for kind, (image, legend) in s.view_maps(0, full).items():
                self.view_images[kind] = gui.add_image(subsample(image, PANEL_IMAGE), label=kind, format="png")
                self.view_legends[kind] = gui.add_html(legend)
        with gui.add_folder("Export", expand_by_default=False):
            self.export_name = gui.add_text("File name", initial_value="cloud")
            self.export_button = gui.add_button("Export cloud (PLY)", disabled=not s.has_maps)
            self.rrd_button = gui.add_button("Save state (.rrd)", disabled=not s.has_maps)
            self.export_status = gui.add_markdown("")
        self.select_view(0)

        self._applying_preset = False
        self.pipeline.on_update(lambda _event: self._pipeline_changed())
        self.fused_confidence_tau.on_update(lambda _event: self._tau_changed())
        self.mask_k.on_update(lambda _event: None if self._applying_preset else self.request(self.params()))
        for handle in self._fusion_handles.values():
            handle.on_update(lambda _event: self._fusion_slider_moved())
        self.preset.on_update(lambda _event: self._apply_preset())
        self.color_mode.on_update(lambda _event: self._color_mode_changed())
        self.point_size.on_update(lambda _event: self._set_point_size())
        self.point_budget.on_update(lambda _event: self.request(self.params()))  # the cached cloud, re-thinned
        self.export_button.on_click(lambda _event: self.export_ply())
        self.rrd_button.on_click(lambda _event: self.save_rrd())
        self.reset_button.on_click(lambda _event: self.reset_to_run())
        self.view_dropdown.on_update(lambda _event: self._view_dropdown_changed())
        self.prev_button.on_click(lambda _event: self.step_view(-1))
        self.next_button.on_click(lambda _event: self.step_view(+1))

    # ---- reasons ----------------------------------------------------------------------------------
    def _pipeline_reason(self) -> str:
        found = self.session.pipelines
        if not found:
            return "no maps: open the output folder of deepc run"
        missing = [p for p in ("fast", "full") if p not in found]
        why = {"fast": "fast needs confidence maps (deepc run --pipeline fast)",
               "full": "full needs refined maps (deepc run --pipeline full)"}
        return "; ".join(why[p] for p in missing) or "every pipeline's maps are here"

    def _control_notes(self, pipeline: str) -> str:
        """Why a control is disabled, one line each (shown under the controls)."""
        s = self.session
        if not s.has_maps:
            return ("*Pipeline, confidence threshold, mask k and fusion* act on the maps of a run: open the output "
                    "folder of deepc run")
        notes = []
        if len(s.pipelines) <= 1:
            notes.append(f"*Pipeline* fixed: {self._pipeline_reason()}")
        if not s.has_confidence:
            notes.append("*Confidence threshold* disabled: the run wrote no confidence maps")
        elif pipeline == "vanilla":
            notes.append("*Confidence threshold* disabled: the vanilla pipeline has no confidence filter")
        if not s.has_counter:
            notes.append("*Mask k* disabled: the run wrote no counter maps")
        return "  \n".join(notes)

    # ---- handlers -----------------------------------------------------------------------------------
    def _pipeline_changed(self) -> None:
        if self._applying_preset:
            return
        pipeline = str(self.pipeline.value)
        self.fused_confidence_tau.disabled = pipeline == "vanilla" or not self.session.has_confidence
        self.fused_confidence_tau.label = tau_label(pipeline)
        self.control_notes.content = self._control_notes(pipeline)
        self.request(self.params())

    def _tau_changed(self) -> None:
        """A value typed into the disabled τ box is put back: it would act on nothing."""
        if self._applying_preset:
            return
        if self.fused_confidence_tau.disabled:
            if float(self.fused_confidence_tau.value) != self._last_tau:
                self._applying_preset = True
                try:
                    self.fused_confidence_tau.value = self._last_tau
                finally:
                    self._applying_preset = False
            return
        self._last_tau = float(self.fused_confidence_tau.value)
        self.request(self.params())

    def _color_mode_changed(self) -> None:
        self.color_legend.content = self.session.cloud_legend(str(self.color_mode.value))
        self._recolor_latest()

    def reset_to_run(self) -> None:
        """Every control back to the run's own settings; one recomputation."""
        run = self.run_params
        self._applying_preset = True
        try:
            self.pipeline.value = run.pipeline
            self.fused_confidence_tau.disabled = run.pipeline == "vanilla" or not self.session.has_confidence
            self.fused_confidence_tau.label = tau_label(run.pipeline)
            self.fused_confidence_tau.value = run.fused_confidence_tau
            self._last_tau = run.fused_confidence_tau
            self.mask_k.value = run.mask_k
            for field, handle in self._fusion_handles.items():
                handle.value = getattr(run.fusion, field)
            self.preset.value = preset_of(run.fusion)
        finally:
            self._applying_preset = False
        self.control_notes.content = self._control_notes(run.pipeline)
        self.request(self.params())

    def _view_dropdown_changed(self) -> None:
        index = int(str(self.view_dropdown.value).split(":", 1)[0])
        if index != self.selected_view:
            self.select_view(index)

    def step_view(self, step: int) -> None:
        """The previous (-1) or next (+1) view, wrapping around."""
        self.select_view((self.selected_view + step) % len(self.session.scene.views))

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

    def cloud_point_size(self) -> float:
        """The point size slider's value in model units."""
        return float(self.point_size.value) / self.size_slider.per_metre

    def params(self) -> ViewParams:
        """The ViewParams the controls describe now."""
        fusion = self._base_fusion.replace(**{field: FUSION_CONTROLS[field](handle.value)
                                              for field, handle in self._fusion_handles.items()})
        pipeline = str(self.pipeline.value)
        # vanilla has no confidence filter: its state says so rather than carrying a τ that acts on nothing
        tau = float(self.fused_confidence_tau.value) if pipeline != "vanilla" else 0.0
        return ViewParams(pipeline=pipeline, fused_confidence_tau=tau, mask_k=int(self.mask_k.value), fusion=fusion)
