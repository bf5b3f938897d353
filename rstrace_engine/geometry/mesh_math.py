"""Per-mesh geometry the scene model needs: which triangles have an area, smooth vertex
normals, the world box of a transformed object box (numpy, float64)."""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol


def proper_triangles(verts: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(m,) bool: the triangles of positive area (doubled area above
    ``DEGENERATE_AREA_REL`` times the longest edge squared); the others are dropped at scene
    build, and a mesh with none is refused."""
    v = np.asarray(verts, np.float64)[tris]
    e0, e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], v[:, 2] - v[:, 1]
    area2 = np.linalg.norm(np.cross(e0, e1), axis=1)
    longest = np.max(np.stack([np.einsum("ij,ij->i", e, e) for e in (e0, e1, e2)]), axis=0)
    return (area2 > tol.DEGENERATE_AREA_REL * longest) & (longest > 0)


def transform_aabb(lo: np.ndarray, hi: np.ndarray, m: np.ndarray) -> np.ndarray:
    """World box (2, 3) of the object box ``lo, hi`` under the affine matrix ``m``."""
    c = 0.5 * (lo + hi)
    e = 0.5 * (hi - lo)
    wc = m[:3, :3] @ c + m[:3, 3]
    we = np.abs(m[:3, :3]) @ e
    return np.stack([wc - we, wc + we])


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted smooth vertex normals, (n, 3) float64, unit (or zero where isolated)."""
    v = vertices[triangles]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    acc = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(acc, triangles[:, k], fn)
    ln = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, ln, out=np.zeros_like(acc), where=ln > 0)
