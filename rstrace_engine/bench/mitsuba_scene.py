"""The Mitsuba 3 scene of an rstrace scene (``bench frame``): the same world-space triangles,
the camera, the lights (point: ``point`` with intensity = our W/sr, spot: ``spot``, sun:
``directional``) and a BSDF per material (by default ``diffuse``, or a perfect ``conductor``
where the mirror dominates; :mod:`.frame_rough` maps Principled materials)."""

from __future__ import annotations

import math

import numpy as np

from ..geometry.attributes import scene_corners, slots_of
from ..geometry.scene import LIGHT_SPOT, LIGHT_SUN, Scene


def world_triangles(scene: Scene):
    """World-space triangle soup grouped by material.

    Returns ``{material_id: (positions (3k, 3) float64, normals (3k, 3) float64)}``: every
    instance's triangles transformed by its matrix (normals by the normal matrix), three
    unshared vertices per triangle so per-corner normals survive.
    """
    sa = scene.arrays()
    normals = scene_corners(sa, "normals")
    groups: dict[int, list] = {}
    for i in range(len(sa.inst_mesh)):
        m = sa.inst_mesh[i]
        t0, t1 = sa.mesh_tri_start[m], sa.mesh_tri_start[m + 1]
        tris = sa.tris[t0:t1]
        xf = sa.inst_xform[i]
        p = sa.verts[tris.reshape(-1)] @ xf[:3, :3].T + xf[:3, 3]
        n = normals[t0:t1].reshape(-1, 3).astype(np.float64) @ sa.inst_nmat[i].T
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        mats = sa.inst_mat[sa.inst_mat_start[i]:sa.inst_mat_start[i + 1]]
        slot = np.minimum(slots_of(sa, np.full(t1 - t0, m), np.arange(t0, t1)), len(mats) - 1)
        for mid in np.unique(mats[slot]):
            sel = np.repeat(mats[slot] == mid, 3)
            groups.setdefault(int(mid), []).append((p[sel], n[sel]))
    return {k: (np.concatenate([a for a, _ in v]), np.concatenate([b for _, b in v]))
            for k, v in groups.items()}


def _plain_bsdf(sa, mid: int) -> dict:
    """The direct integrator's material: a perfect conductor where the mirror dominates,
    else Lambertian."""
    mirror = sa.mat_mirror[mid]
    if mirror.max() > sa.mat_diffuse[mid].max():
        return {"type": "conductor", "material": "none",
                "specular_reflectance": {"type": "rgb", "value": mirror.tolist()}}
    return {"type": "diffuse",
            "reflectance": {"type": "rgb", "value": sa.mat_diffuse[mid].tolist()}}


def mitsuba_scene_dict(scene: Scene, mi, width: int, height: int, bsdf=None,
                       spp: int = 1) -> dict:
    """The Mitsuba 3 scene dict for ``scene`` (the module docstring says what becomes what).
    ``bsdf(material_id) -> dict`` maps materials (default: :func:`_plain_bsdf`)."""
    sa = scene.arrays()
    cam = scene.camera
    m = np.asarray(cam.matrix, np.float64)
    eye = m[:3, 3]
    fwd = -m[:3, 2] / np.linalg.norm(m[:3, 2])
    up = m[:3, 1] / np.linalg.norm(m[:3, 1])
    horizontal = cam.sensor_fit == "HORIZONTAL" or (cam.sensor_fit == "AUTO" and
                                                    width >= height)
    sensor = cam.sensor_width if cam.sensor_fit in ("AUTO", "HORIZONTAL") else cam.sensor_height
    fov = math.degrees(2.0 * math.atan(0.5 * sensor / cam.lens))
    T = mi.ScalarTransform4f
    d: dict = {
        "type": "scene",
        "integrator": {"type": "direct", "bsdf_samples": 0,
                       "emitter_samples": max(1, len(sa.light_kind))},
        "sensor": {
            "type": "perspective", "fov": fov, "fov_axis": "x" if horizontal else "y",
            "near_clip": float(cam.clip_start), "far_clip": float(cam.clip_end),
            "to_world": T().look_at(origin=eye.tolist(), target=(eye + fwd).tolist(),
                                    up=up.tolist()),
            "sampler": {"type": "independent", "sample_count": int(spp)},
            "film": {"type": "hdrfilm", "width": width, "height": height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        },
    }
    for mid, (pos, nrm) in world_triangles(scene).items():
        nv = len(pos)
        mesh = mi.Mesh(f"mat{mid}", vertex_count=nv, face_count=nv // 3,
                       has_vertex_normals=True)
        params = mi.traverse(mesh)
        params["vertex_positions"] = pos.astype(np.float32).ravel()
        params["vertex_normals"] = nrm.astype(np.float32).ravel()
        params["faces"] = np.arange(nv, dtype=np.uint32)
        params.update()
        mesh.set_bsdf(mi.load_dict(_plain_bsdf(sa, mid) if bsdf is None else bsdf(mid)))
        d[f"mesh{mid}"] = mesh
    for j in range(len(sa.light_kind)):
        rgb = {"type": "rgb", "value": sa.light_intensity[j].tolist()}
        pos = sa.light_pos[j]
        ldir = sa.light_dir[j]
        if sa.light_kind[j] == LIGHT_SUN:
            d[f"light{j}"] = {"type": "directional", "direction": ldir.tolist(),
                              "irradiance": rgb}
        elif sa.light_kind[j] == LIGHT_SPOT:
            up_l = (0.0, 0.0, 1.0) if abs(ldir[2]) < 0.9 else (0.0, 1.0, 0.0)
            d[f"light{j}"] = {
                "type": "spot", "intensity": rgb,
                "cutoff_angle": math.degrees(math.acos(sa.light_cos_outer[j])),
                "beam_width": math.degrees(math.acos(min(1.0, sa.light_cos_inner[j]))),
                "to_world": T().look_at(origin=pos.tolist(), target=(pos + ldir).tolist(),
                                        up=up_l),
            }
        else:
            d[f"light{j}"] = {"type": "point", "position": pos.tolist(), "intensity": rgb}
    return d
