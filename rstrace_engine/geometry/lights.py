"""Lights of the scene model: validation (:func:`checked_light`) and the packing of lights
with an extent into the scene's arrays (:class:`ExtendedLights`), as Cycles defines them."""

from __future__ import annotations

import math

import numpy as np

from .. import tolerances as tol
from .elements import (
    AREA_SHAPES,
    LIGHT_KINDS,
    LIGHT_NONE,
    MAX_LIGHT_POWER,
    Light,
    SceneError,
    _colour,
)


def _light_number(name: str, label: str, value, lo: float, hi: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SceneError(f"light '{name}': {label} {value!r} is not a number") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise SceneError(f"light '{name}': {label} {v} outside [{lo:g}, {hi:g}]")
    return v


def _area_size(name: str, shape: str, size) -> tuple:
    """The full extents of an area light (a square or disk has one)."""
    try:
        sz = np.asarray(size, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise SceneError(f"light '{name}': size {size!r} is not numbers") from None
    if sz.size == 1 or shape in ("SQUARE", "DISK"):
        sz = np.array([sz[0], sz[0]])
    if sz.size != 2:
        raise SceneError(f"light '{name}': size needs 1 or 2 values, got {sz.size}")
    if not np.all(np.isfinite(sz)):
        raise SceneError(f"light '{name}': size {sz.tolist()} has NaN or infinite values")
    if np.any(sz <= 0.0) or np.any(sz > tol.COORD_MAX):
        what = "an axis of the ellipse" if shape == "ELLIPSE" else "a side"
        raise SceneError(f"light '{name}': size {sz.tolist()}: {what} is zero, negative or "
                         f"too large (a zero-size area light is a point)")
    return (float(sz[0]), float(sz[1]))




def _area_axis(name: str, axis, direction: np.ndarray) -> tuple:
    """The emitter's unit +X, made exactly orthogonal to ``direction``."""
    a = np.asarray(axis, dtype=np.float64).reshape(-1)
    ln = float(np.linalg.norm(a)) if a.size == 3 and np.all(np.isfinite(a)) else 0.0
    if ln == 0.0:
        raise SceneError(f"light '{name}': axis is zero, NaN, infinite or not 3 values")
    if abs(ln - 1.0) > tol.UNIT_SLACK:
        a = a / ln
    c = float(a @ direction)
    if abs(c) > tol.AREA_AXIS_COS_MAX:
        raise SceneError(f"light '{name}': axis is not orthogonal to the direction "
                         f"(cosine {c:.3g})")
    if abs(c) <= tol.UNIT_SLACK and abs(float(np.linalg.norm(a)) - 1.0) <= tol.UNIT_SLACK:
        return tuple(a)  # already a unit axis orthogonal to the direction: kept as given
    a = a - c * direction
    return tuple(a / np.linalg.norm(a))


class ExtendedLights:
    """The packing of lights with an extent, as Cycles defines them (the radiance a
    sampled direction carries):

    * sphere (POINT, SPOT with a radius r): ``c P / (4 pi^2 r^2)`` over the sphere seen
      from the point; with soft falloff over the cap of sine ``r / sqrt(r^2 + d^2)``
      instead (the far field then equals the point light's ``P / (4 pi (d^2 + r^2))``);
    * SUN with angular diameter a: ``c S / (pi sin^2(a / 2))`` over its cone (a surface
      facing it gets irradiance ``c S``);
    * AREA: ``c P / (pi A)`` on its emitting side (A its area: a Lambertian emitter of
      exitance P / A), times the spread attenuation ``max(0, (tan(s/2) - tan(theta)) /
      (tan(s/2) - s/2))`` when the spread s is below pi (Cycles' soft-box model, which
      keeps the power; ``3 / (s/2)^3`` for the normaliser when s/2 <= 0.05, as Cycles).

    (Checked against Cycles 4.2-5.0 renders: docs/cycles-lights.md, sections 1-5.)
    """

    def __init__(self, nl: int) -> None:
        self.a = dict(
            light_ext=np.zeros(nl, np.bool_), light_radiance=np.zeros((nl, 3)),
            light_radius=np.zeros(nl), light_soft=np.zeros(nl, np.bool_),
            light_half=np.zeros(nl), light_u=np.zeros((nl, 3)),
            light_v=np.zeros((nl, 3)), light_size=np.zeros((nl, 2)),
            light_ellipse=np.zeros(nl, np.bool_), light_spread=np.zeros((nl, 2)),
            light_bound=np.zeros(nl))
        self.a["light_spread"][:, 0] = np.inf

    def pack(self, j: int, li: Light) -> None:
        a = self.a
        c = np.asarray(li.color, np.float64)
        if not li.extended:
            return
        a["light_ext"][j] = True
        if li.kind == "SUN":
            half = 0.5 * li.angle
            a["light_half"][j] = half
            a["light_radiance"][j] = c * li.power / (math.pi * math.sin(half) ** 2)
        elif li.kind == "AREA":
            su, sv = li.size
            u = np.asarray(li.axis, np.float64)
            v = np.cross(-np.asarray(li.direction, np.float64), u)
            ellipse = li.shape in ("DISK", "ELLIPSE")
            area = su * sv * (math.pi / 4.0 if ellipse else 1.0)
            a["light_u"][j] = u
            a["light_v"][j] = v / np.linalg.norm(v)
            a["light_size"][j] = (su, sv)
            a["light_ellipse"][j] = ellipse
            a["light_radiance"][j] = c * li.power / (math.pi * area)
            a["light_bound"][j] = 0.5 * math.hypot(su, sv)
            if li.spread < math.pi:
                half = 0.5 * max(li.spread, tol.AREA_SPREAD_MIN)
                norm = 3.0 / half ** 3 if half <= 0.05 else 1.0 / (math.tan(half) - half)
                a["light_spread"][j] = (math.tan(half), norm)
        else:
            r = li.radius
            a["light_radius"][j] = r
            a["light_soft"][j] = bool(li.soft_falloff)
            a["light_radiance"][j] = c * li.power / (4.0 * math.pi ** 2 * r * r)
            a["light_bound"][j] = r

    def arrays(self) -> dict:
        return self.a


def seen_extent(li: Light):
    """Where rays see light ``li``'s own surface (:mod:`~..tracing.seen_lights`): None
    when none does (no extent, or its camera, glossy and transmission visibility off),
    True for a sun (the sky: rays that hit nothing), else its world box (2, 3)."""
    if not li.extended or not (li.camera or li.glossy or li.transmission):
        return None
    if li.kind == "SUN":
        return True
    if li.kind == "AREA":
        r = 0.5 * math.hypot(*li.size)
    else:
        r = li.radius
    p = np.asarray(li.position, np.float64)
    return np.stack([p - r, p + r])


def checked_light(light: Light) -> Light:
    """``light`` validated (errors name the light and setting) and normalised: a unit
    direction and area axis, extents below ``LIGHT_EXTENT_MIN`` made a point."""
    n = light.name
    if light.kind not in LIGHT_KINDS:
        raise SceneError(f"light '{n}': unknown kind {light.kind!r} "
                         f"(expected one of {sorted(LIGHT_KINDS)})")
    col = _colour(n, f"light '{n}' colour", light.color, hi=None)
    try:
        p = float(light.power)
    except (TypeError, ValueError):
        raise SceneError(f"light '{n}': power {light.power!r} is not a number") from None
    if not (math.isfinite(p) and 0.0 <= p <= MAX_LIGHT_POWER):
        raise SceneError(f"light '{n}': power {p} outside [0, {MAX_LIGHT_POWER:g}]")
    pos = _colour(n, f"light '{n}' position", light.position, lo=-tol.COORD_MAX,
                  hi=tol.COORD_MAX)
    d = np.asarray(light.direction, dtype=np.float64).reshape(3)
    ln = float(np.linalg.norm(d)) if np.all(np.isfinite(d)) else 0.0
    if ln == 0.0:
        raise SceneError(f"light '{n}': direction is zero, NaN or infinite")
    size = float(light.spot_size)
    blend = float(light.spot_blend)
    if light.kind == "SPOT" and not (0.0 < size <= math.pi and 0.0 <= blend <= 1.0):
        raise SceneError(f"light '{n}': spot size {size} / blend {blend} out of range")
    if abs(ln - 1.0) > tol.UNIT_SLACK:  # (idempotent: a light given back is unchanged)
        d = d / ln
    radius = _light_number(n, "radius", light.radius, 0.0, tol.COORD_MAX)
    angle = _light_number(n, "angle", light.angle, 0.0, math.pi)
    # below these a sphere or a sun's cone is a point or a direction to float64 (its
    # radiance over its size would overflow): the light is one
    radius = 0.0 if radius < tol.LIGHT_EXTENT_MIN else radius
    angle = 0.0 if angle < tol.LIGHT_EXTENT_MIN else angle
    spread = _light_number(n, "spread", light.spread, 0.0, math.pi)
    shape = light.shape
    axis, ext = (1.0, 0.0, 0.0), (1.0, 1.0)
    if light.kind == "AREA":
        if shape not in AREA_SHAPES:
            raise SceneError(f"light '{n}': unknown area shape {shape!r} (expected one "
                             f"of {list(AREA_SHAPES)})")
        ext = _area_size(n, shape, light.size)
        axis = _area_axis(n, light.axis, d)
        if spread <= 0.0:
            raise SceneError(f"light '{n}': spread 0 (a collimated beam) is not "
                             f"modelled")
    frame = _spot_frame(n, light.spot_frame) if light.kind == "SPOT" else ()
    return Light(n, light.kind, tuple(col), p, tuple(pos), tuple(d), size, blend,
                 radius, bool(light.soft_falloff), angle, shape, axis, ext, spread,
                 bool(light.diffuse), bool(light.glossy), frame,
                 _links(n, "receiver", light.receivers), _links(n, "blocker", light.blockers),
                 bool(light.camera), bool(light.transmission))


def _spot_frame(name: str, frame) -> tuple:
    """A spot's world 3 x 3 matrix (9 values, row-major), or ``()`` for a round cone: also
    where its columns are orthogonal and of one length (the cone is then not reshaped)."""
    if frame is None or len(frame) == 0:
        return ()
    m = np.asarray(frame, dtype=np.float64).reshape(-1)
    if m.size != 9 or not np.all(np.isfinite(m)):
        raise SceneError(f"light '{name}': spot frame needs 9 finite values")
    m = m.reshape(3, 3)
    lens = np.linalg.norm(m, axis=0)
    if not np.all(lens > 0.0):
        raise SceneError(f"light '{name}': spot frame has a zero axis")
    u = m / lens
    skew = np.abs(u.T @ u - np.eye(3)).max()
    if lens.max() - lens.min() <= tol.SPOT_FRAME_SLACK * lens.max() and \
            skew <= tol.SPOT_FRAME_SLACK:
        return ()
    return tuple(float(x) for x in m.reshape(-1))


def _links(name: str, what: str, links) -> tuple:
    """Light-linking entries ``((object name, include), ...)``, checked."""
    out = []
    for entry in links or ():
        try:
            obj, inc = entry
        except (TypeError, ValueError):
            raise SceneError(f"light '{name}': {what} entry {entry!r} is not (object name, "
                             f"include)") from None
        out.append((str(obj), bool(inc)))
    return tuple(out)


def link_mask(links: tuple, names: list) -> np.ndarray | None:
    """Which of the objects ``names`` a light's linking entries ``links`` take in (as
    Blender's light linking: with some objects included, only those; excluded objects
    never), or None when ``links`` is empty (every object). An instance named
    ``"instancer/object"`` (the add-on's names) goes with its instancer, as in Blender."""
    if not links:
        return None
    inc = {n for n, i in links if i}
    exc = {n for n, i in links if not i}

    def member(n, group):
        return n is not None and (n in group or n.split("/", 1)[0] in group)
    return np.array([(member(n, inc) if inc else n is not None) and not member(n, exc)
                     for n in names], np.bool_)


class LightReach:
    """The per-light arrays of what a light reaches: ``light_vis`` (L, 4) its diffuse and
    glossy factors (1 or 0), then whether camera and smooth refraction rays see it (the
    glossy factor says it for mirror rays: :mod:`~..tracing.seen_lights`),
    ``light_spot_scaled`` (L,) and ``light_spot_frame`` (L, 3, 3) the rows that take a
    direction from the light into the spot's scaled frame (Cycles'
    ``scaled_axis_u``, ``scaled_axis_v`` and the direction over its length), and the
    linking tables ``light_recv`` and ``light_block`` (L, I) uint8, (0, 0) where no light
    links (a scene without linking carries nothing)."""

    def __init__(self, lights: list, names: list) -> None:
        nl = len(lights)
        vis = np.ones((nl, 4))
        scaled = np.zeros(nl, np.bool_)
        frame = np.zeros((nl, 3, 3))
        recv = [None] * nl
        block = [None] * nl
        for j, li in enumerate(lights):
            if li is None:
                continue
            vis[j] = (float(li.diffuse), float(li.glossy), float(li.camera),
                      float(li.transmission))
            if li.spot_frame:
                m = np.asarray(li.spot_frame, np.float64).reshape(3, 3)
                lens = np.linalg.norm(m, axis=0)
                # columns X, Y and -Z (the way the spot points), each over its length
                # twice: unit axis / scale
                frame[j] = np.stack([m[:, 0] / lens[0] ** 2, m[:, 1] / lens[1] ** 2,
                                     -m[:, 2] / lens[2] ** 2])
                scaled[j] = True
            recv[j] = link_mask(li.receivers, names)
            block[j] = link_mask(li.blockers, names)
        self.a = dict(light_vis=vis, light_spot_scaled=scaled, light_spot_frame=frame,
                      light_recv=_table(recv, len(names)),
                      light_block=_table(block, len(names)))

    def arrays(self) -> dict:
        return self.a


def _table(masks: list, ni: int) -> np.ndarray:
    """(L, I) uint8 of the masks (None: every object), or (0, 0) when all are None."""
    if all(m is None for m in masks):
        return np.zeros((0, 0), np.uint8)
    t = np.ones((len(masks), ni), np.uint8)
    for j, m in enumerate(masks):
        if m is not None:
            t[j] = m
    return t


def pack_lights(lights: list, names: list) -> dict:
    """The :class:`~.scene.SceneArrays` fields of the light slots ``lights`` (``None``: a
    deleted light's slot, kind ``LIGHT_NONE``, zero intensity) whose linking names the
    instances ``names`` (:class:`LightReach`): kind, position, direction, intensity (a
    point, spot or area light's W / (4 pi) per unit colour, a sun's W/m^2), spot cones
    (Cycles: ``smoothstep((cos - cos_outer) / ((1 - cos_outer) blend))``), the extents
    (:class:`ExtendedLights`) and the reach."""
    nl = len(lights)
    kind = np.full(nl, LIGHT_NONE, np.int32)
    pos = np.zeros((nl, 3))
    ldir = np.zeros((nl, 3))
    ldir[:, 2] = -1.0
    intensity = np.zeros((nl, 3))
    cos_outer = np.full(nl, -1.0)
    cos_inner = np.full(nl, -1.0)
    ext = ExtendedLights(nl)
    for j, li in enumerate(lights):
        if li is None:
            continue
        ext.pack(j, li)
        kind[j] = LIGHT_KINDS[li.kind]
        pos[j] = li.position
        ldir[j] = li.direction
        c = np.asarray(li.color)
        intensity[j] = c * li.power if li.kind == "SUN" else c * li.power / (4 * math.pi)
        if li.kind == "SPOT":
            cos_outer[j] = math.cos(0.5 * li.spot_size)
            cos_inner[j] = cos_outer[j] + (1.0 - cos_outer[j]) * li.spot_blend
    return dict(light_kind=kind, light_pos=pos, light_dir=ldir, light_intensity=intensity,
                light_cos_outer=cos_outer, light_cos_inner=cos_inner, **ext.arrays(),
                **LightReach(lights, names).arrays())
