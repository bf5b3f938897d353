"""Render settings and the rendered frame, shared by the tracers and the Blender engine."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import SceneError

#: Every render mode, and the ones this version implements (the only lists: the session,
#: the command line and the Blender add-on all read these).
MODES = ("BASE", "INTERPOLANT", "RI_TREE")
AVAILABLE_MODES = ("BASE", "INTERPOLANT", "RI_TREE")
#: Every accelerator name, and the ones this version implements (``EMBREE`` also needs the
#: ``embreex`` package at run time: :func:`~.accel.accelerators.create_accelerator` says so).
ACCELERATORS = ("BVH", "EMBREE", "BRUTE_FORCE", "VISIBILITY_FIELD")
AVAILABLE_ACCELERATORS = ("BVH", "EMBREE", "BRUTE_FORCE", "VISIBILITY_FIELD")
#: Not offered in the Blender add-on: brute force is the tests' reference, far too slow for
#: a real scene.
INTERNAL_ACCELERATORS = ("BRUTE_FORCE",)
#: deepest RI-tree depth constraint accepted (cells of 2^-16 of a face per axis)
RI_MAX_DEPTH = 64

# The structures' own limits live here, below them in the import order: the structures read
# them from here and :meth:`RenderSettings.validated` checks the settings against them.
#: Deepest linetree cell a ``depth_cap`` may ask for (:data:`.interpolants.linetree.MAX_DEPTH`;
#: the linetree's sample lattice lies two levels further down).
LINETREE_MAX_DEPTH = 12
#: Shadow rays per light with an extent and per shading point (RenderSettings.light_samples)
LIGHT_SAMPLES_DEFAULT = 16
LIGHT_SAMPLES_MAX = 4096
#: Glossy rays a path draws at its first rough (glossy) bounce (RenderSettings.glossy_samples;
#: by lobe, tracing.glossy_rays.glossy_counts; deeper rough bounces draw one), docs/glossy.md
GLOSSY_SAMPLES_DEFAULT = 16
GLOSSY_SAMPLES_MAX = 1024
#: Visibility field: most directions (the tetrahedron subdivided to
#: :data:`.accel.directions.MAX_LEVEL`), most tiles per side, memory cap of one field (MB).
VF_MAX_DIRECTIONS = 2050
VF_MAX_TILES = 1024
VF_MEMORY_CAP_MB = 2048.0

# Per-pixel classes (the paper's Plate B), stored in Frame.pixel_class.
CLASS_BACKGROUND = 0
CLASS_TRACED = 1  # traced by the base tracer (BASE mode, or no interpolant applies)
CLASS_INTERPOLATED = 2
CLASS_FAIL_SILHOUETTE = 3  # failed at a silhouette or a miss
CLASS_FAIL_SHADOW = 4  # failed at a shadow / visibility change
CLASS_FAIL_NONLINEAR = 5  # failed by non-linearity at the depth cap
CLASS_REBUILT = 6  # interpolant rebuilt after an edit

CLASS_NAMES = ("background", "traced", "interpolated", "fail_silhouette", "fail_shadow",
               "fail_nonlinear", "rebuilt")
# False colours for the Interpolation pass (linear RGB), after the paper's Plate B.
CLASS_COLORS = np.array([
    [0.0, 0.0, 0.0],  # background: black
    [0.5, 0.5, 0.5],  # traced: grey
    [0.1, 0.7, 0.1],  # interpolated: green
    [0.9, 0.1, 0.1],  # silhouette / miss: red
    [0.1, 0.2, 0.9],  # shadow / visibility: blue
    [0.9, 0.8, 0.1],  # non-linearity at the depth cap: yellow
    [0.9, 0.2, 0.9],  # rebuilt after an edit: magenta
], dtype=np.float32)


def check_vf_settings(directions: int, tiles: int, memory_cap_mb: float) -> None:
    """Raise :class:`SceneError` naming a visibility field setting outside its range."""
    if not 1 <= int(directions) <= VF_MAX_DIRECTIONS:
        raise SceneError(f"setting 'vf_directions': {directions} outside "
                         f"[1, {VF_MAX_DIRECTIONS}]")
    if not 1 <= int(tiles) <= VF_MAX_TILES:
        raise SceneError(f"setting 'vf_tiles': {tiles} outside [1, {VF_MAX_TILES}]")
    if not (np.isfinite(memory_cap_mb) and memory_cap_mb > 0):
        raise SceneError(f"visibility field: memory cap {memory_cap_mb} MB must be > 0")


@dataclass
class RenderSettings:
    """What the user controls. Validated by :meth:`validated` (clear messages)."""

    mode: str = "BASE"
    epsilon: float = 0.01  # display-space error bound for interpolants
    max_depth: int = 5  # Whitted ray depth (0: primary rays and direct light only)
    samples: int = 1  # jittered samples per pixel
    # shadow rays per light with an extent (area, sphere, sun with an angle) and for the
    # world's light, per shading point (docs/SOFT_LIGHT.md: the default by measurement)
    light_samples: int = LIGHT_SAMPLES_DEFAULT
    # rays at a path's first rough reflection/refraction (deeper ones: 1; docs/glossy.md)
    glossy_samples: int = GLOSSY_SAMPLES_DEFAULT
    accelerator: str = "BVH"
    depth_cap: int = 6  # linetree depth cap
    memory_cap_mb: float = 256.0  # interpolant memory cap
    seed: int = 0
    vf_directions: int = 34  # visibility field: directions l (rounded up to 4, 10, 34, 130..)
    vf_tiles: int = 64  # visibility field: n x n tiles per direction

    # RI-tree (seed 004); the paper's ranges are the panel's soft limits
    ri_dist_thresh: float = 0.05  # distance threshold (4D line space), 0.01-0.25
    ri_ang_thresh: float = 30.0  # angular threshold, degrees, 5-30
    ri_depth: int = 28  # depth constraint of the binary 4D kd-trees, 22-30
    ri_cache_mb: float = 100.0  # RI-tree cache size, MB
    # exit-ray test (an addition to seed 004): largest angle, degrees, between a cell's
    # traced and interpolated output ray at its midpoint; 0: off (the paper's tests alone)
    ri_probe_angle: float = 0.025
    thickness_view: bool = False  # render distance travelled inside objects (seed 004 3.7)
    thickness_distance: float = 0.0  # 1/e distance of the thickness view; 0: scene / 10
    relight_memory_mb: float = 512.0  # BASE: per-light records cap (MB; 0: none kept)
    # INTERPOLANT: trace where cells do not pay, learned from the frames' measured costs
    # (interpolants/fallback.py); off: cells wherever the rays need them (to see them)
    interpolant_fallback: bool = True

    def accelerator_options(self) -> dict:
        """Keyword options of :func:`~rstrace_engine.accel.accelerators.create_accelerator`."""
        return {"directions": int(self.vf_directions), "tiles": int(self.vf_tiles)}

    def validated(self) -> RenderSettings:
        if self.mode not in MODES:
            raise SceneError(f"setting 'mode': {self.mode!r} not one of {MODES}")
        if self.accelerator not in ACCELERATORS:
            raise SceneError(f"setting 'accelerator': {self.accelerator!r} not one of "
                             f"{ACCELERATORS}")
        if not (np.isfinite(self.epsilon) and 0.0 <= self.epsilon <= 1.0):
            raise SceneError(f"setting 'epsilon': {self.epsilon} outside [0, 1]")
        if not 0 <= int(self.max_depth) <= 32:
            raise SceneError(f"setting 'max_ray_depth': {self.max_depth} outside [0, 32]")
        if not 1 <= int(self.samples) <= 4096:
            raise SceneError(f"setting 'samples': {self.samples} outside [1, 4096]")
        if not 1 <= int(self.light_samples) <= LIGHT_SAMPLES_MAX:
            raise SceneError(f"setting 'light_samples': {self.light_samples} outside "
                             f"[1, {LIGHT_SAMPLES_MAX}] (shadow rays per light with an "
                             f"extent, per shading point)")
        if not 1 <= int(self.glossy_samples) <= GLOSSY_SAMPLES_MAX:
            raise SceneError(f"setting 'glossy_samples': {self.glossy_samples} outside "
                             f"[1, {GLOSSY_SAMPLES_MAX}] (rays at a path's first rough "
                             f"reflection or refraction)")
        if not 0 <= int(self.depth_cap) <= LINETREE_MAX_DEPTH:
            raise SceneError(f"setting 'depth_cap': {self.depth_cap} outside "
                             f"[0, {LINETREE_MAX_DEPTH}]")
        if not (np.isfinite(self.memory_cap_mb) and self.memory_cap_mb >= 0.0):
            raise SceneError(f"setting 'memory_cap_mb': {self.memory_cap_mb} must be >= 0")
        check_vf_settings(self.vf_directions, self.vf_tiles, VF_MEMORY_CAP_MB)
        for name, lo, hi in (("ri_dist_thresh", 0.0, 10.0), ("ri_ang_thresh", 0.0, 180.0)):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and lo < v <= hi):
                raise SceneError(f"setting '{name}': {v} outside ({lo:g}, {hi:g}]")
        if not (np.isfinite(self.ri_probe_angle) and 0.0 <= self.ri_probe_angle <= 180.0):
            raise SceneError(f"setting 'ri_probe_angle': {self.ri_probe_angle} outside "
                             f"[0, 180] degrees (0: off)")
        if not 1 <= int(self.ri_depth) <= RI_MAX_DEPTH:
            raise SceneError(f"setting 'ri_depth': {self.ri_depth} outside [1, {RI_MAX_DEPTH}]")
        if not (np.isfinite(self.ri_cache_mb) and 0.0 < self.ri_cache_mb <= 1e6):
            raise SceneError(f"setting 'ri_cache_mb': {self.ri_cache_mb} outside (0, 1e6] MB")
        if not (np.isfinite(self.relight_memory_mb) and 0.0 <= self.relight_memory_mb <= 1e6):
            raise SceneError(f"setting 'relight_memory_mb': {self.relight_memory_mb} outside "
                             f"[0, 1e6] MB (the per-light records' cap; light edits re-trace "
                             f"pixels above it; 0: no records)")
        if not (np.isfinite(self.thickness_distance) and self.thickness_distance >= 0.0):
            raise SceneError(f"setting 'thickness_distance': {self.thickness_distance} must "
                             f"be >= 0 (0: automatic)")
        return self


@dataclass
class Frame:
    """A rendered image. Rows are bottom-up (row 0 is the bottom), as in Blender."""

    radiance: np.ndarray  # (h, w, 3) float32 linear RGB
    pixel_class: np.ndarray  # (h, w) uint8, one of the CLASS_* values
    stats: dict = field(default_factory=dict)
    # (h, w) int32 id of the interpolant each pixel used (-1: traced or background); set by
    # INTERPOLANT frames so an edit can find the pixels of the interpolants it invalidated.
    pixel_interpolant: np.ndarray | None = None

    def class_image(self) -> np.ndarray:
        """(h, w, 3) float32 false-colour image of the pixel classes."""
        return CLASS_COLORS[self.pixel_class]
