"""Mesh generators (object space) for tests, benchmarks and the demo.

Each returns a :class:`~rstrace_engine.geometry.scene.Mesh`; none of this is used by the hot paths.
"""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol
from .scene import Mesh


def icosphere(subdivisions: int = 3, radius: float = 1.0, name: str = "icosphere") -> Mesh:
    """A geodesic sphere: 20 * 4**subdivisions triangles, smooth normals, spherical uvs."""
    t = (1.0 + 5 ** 0.5) / 2.0
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
             (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9),
             (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2),
             (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
             (8, 6, 7), (9, 8, 1)]
    v = np.array(verts, dtype=np.float64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    f = np.array(faces, dtype=np.int64)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mids = v[uniq[:, 0]] + v[uniq[:, 1]]
        mids /= np.linalg.norm(mids, axis=1, keepdims=True)
        base = len(v)
        v = np.concatenate([v, mids])
        m = inv.reshape(3, -1).T + base  # midpoints of edges (01, 12, 20)
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        ab, bc, ca = m[:, 0], m[:, 1], m[:, 2]
        f = np.concatenate([np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1),
                            np.stack([c, ca, bc], 1), np.stack([ab, bc, ca], 1)])
    normals = v[f].astype(np.float32)
    uv = np.stack([0.5 + np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi),
                   0.5 + np.arcsin(np.clip(v[:, 2], -1, 1)) / np.pi], axis=1)
    return Mesh(name, v * radius, f.astype(np.int32), corner_normals=normals,
                corner_uvs=uv[f].astype(np.float32))


def lumpy_sphere(triangles: int, radius: float = 1.0, name: str = "lumpy") -> Mesh:
    """A latitude-longitude sphere of about ``triangles`` triangles (rings x 2 rings quads),
    its radius displaced by a few sine waves (5% and 2%): a stand-in for a dense scanned or
    subdivided surface. The rings stop half a ring short of the poles (no degenerate
    triangles: two tiny holes there)."""
    rings = max(int(round((triangles / 4) ** 0.5)), 2)
    segs = 2 * rings
    th = (np.arange(rings + 1) + 0.5) / (rings + 1) * np.pi
    ph = np.arange(segs) * (2 * np.pi / segs)
    T, P = np.meshgrid(th, ph, indexing="ij")
    r = radius * (1 + 0.05 * np.sin(7 * T) * np.sin(9 * P) + 0.02 * np.sin(23 * T + 3 * P))
    v = np.stack([r * np.sin(T) * np.cos(P), r * np.sin(T) * np.sin(P), r * np.cos(T)],
                 -1).reshape(-1, 3)
    idx = np.arange((rings + 1) * segs).reshape(rings + 1, segs)
    a, b = idx[:-1], np.roll(idx[:-1], -1, 1)
    c, d = idx[1:], np.roll(idx[1:], -1, 1)
    f = np.stack([np.stack([a, c, d], -1), np.stack([a, d, b], -1)], 2).reshape(-1, 3)
    return Mesh(name, v, f.astype(np.int32))


def uv_sphere(segments: int = 32, rings: int = 16, radius: float = 1.0,
              name: str = "uv_sphere") -> Mesh:
    """A latitude/longitude sphere with smooth normals."""
    th = np.linspace(0, np.pi, rings + 1)
    ph = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    T, P = np.meshgrid(th[1:-1], ph, indexing="ij")
    ring = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]])
    faces = []
    n = segments
    for j in range(n):
        faces.append((0, 1 + j, 1 + (j + 1) % n))
    for r in range(rings - 2):
        for j in range(n):
            a, b = 1 + r * n + j, 1 + r * n + (j + 1) % n
            c, d = a + n, b + n
            faces += [(a, c, b), (b, c, d)]
    last = len(v) - 1
    base = 1 + (rings - 2) * n
    for j in range(n):
        faces.append((base + j, last, base + (j + 1) % n))
    f = np.array(faces, dtype=np.int32)
    return Mesh(name, v * radius, f, corner_normals=v[f].astype(np.float32))


def plane(size_x: float = 2.0, size_y: float | None = None, divisions: int = 1,
          name: str = "plane") -> Mesh:
    """A flat grid in the XY plane, normal +Z, centred at the origin, uvs in [0, 1]."""
    size_y = size_x if size_y is None else size_y
    n = max(int(divisions), 1)
    xs = np.linspace(-size_x / 2, size_x / 2, n + 1)
    ys = np.linspace(-size_y / 2, size_y / 2, n + 1)
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    uv = np.stack([(X.ravel() - xs[0]) / size_x, (Y.ravel() - ys[0]) / size_y], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    return Mesh(name, v, f, corner_normals=np.tile(np.float32([0, 0, 1]), (len(f), 3, 1)),
                corner_uvs=uv[f].astype(np.float32))


def box(size=(1.0, 1.0, 1.0), name: str = "box", inward: bool = False) -> Mesh:
    """An axis-aligned box centred at the origin with flat faces (12 triangles).

    ``inward=True`` flips the faces so the normals point inside (a room).
    """
    sx, sy, sz = (np.asarray(size, dtype=np.float64) / 2).tolist()
    v = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = []
    for a, b, c, d in quads:
        f += [(a, b, c), (a, c, d)]
    f = np.array(f, dtype=np.int32)
    if inward:
        f = f[:, ::-1].copy()
    return Mesh(name, v, f, smooth=False)


def torus(major: float = 1.0, minor: float = 0.35, segments: int = 48, sides: int = 24,
          name: str = "torus") -> Mesh:
    """A smooth torus around +Z: a non-convex test object."""
    u = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    w = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    U, W = np.meshgrid(u, w, indexing="ij")
    centre = np.stack([np.cos(U), np.sin(U), np.zeros_like(U)], -1)
    nrm = np.stack([np.cos(W) * np.cos(U), np.cos(W) * np.sin(U), np.sin(W)], -1)
    v = (centre * major + nrm * minor).reshape(-1, 3)
    nrm = nrm.reshape(-1, 3)
    idx = np.arange(segments * sides).reshape(segments, sides)
    a = idx
    b = np.roll(idx, -1, axis=0)
    c = np.roll(idx, -1, axis=1)
    d = np.roll(b, -1, axis=1)
    f = np.concatenate([np.stack([a.ravel(), b.ravel(), d.ravel()], 1),
                        np.stack([a.ravel(), d.ravel(), c.ravel()], 1)]).astype(np.int32)
    return Mesh(name, v, f, corner_normals=nrm[f].astype(np.float32))


def transform(translate=(0.0, 0.0, 0.0), scale=1.0, rotate_z_deg: float = 0.0,
              rotate_x_deg: float = 0.0) -> np.ndarray:
    """A 4x4 object-to-world matrix: scale, then rotate about X then Z, then translate."""
    s = np.diag(np.broadcast_to(np.asarray(scale, dtype=np.float64), 3))
    ax, az = np.radians(rotate_x_deg), np.radians(rotate_z_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rz @ rx @ s
    m[:3, 3] = translate
    return m


def orbit_z(degrees: float, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A 4x4 rotation by ``degrees`` about the vertical axis through ``centre`` (an orbit:
    ``orbit_z(a, c) @ camera.matrix`` turns a camera about ``c``)."""
    c = np.asarray(centre, dtype=np.float64)
    return transform(c) @ transform(rotate_z_deg=degrees) @ transform(-c)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world matrix of a camera at ``eye`` looking at ``target`` (Blender axes)."""
    eye = np.asarray(eye, dtype=np.float64)
    fwd = np.asarray(target, dtype=np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < tol.LOOK_AT_PARALLEL:
        right = np.cross(fwd, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, fwd)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, cam_up, -fwd, eye
    return m


def _bspline_basis(t: np.ndarray):
    """Uniform cubic B-spline basis (4, n) and its derivative at local parameters t (n,)."""
    t2, t3 = t * t, t * t * t
    b = np.stack([(1 - t) ** 3, 3 * t3 - 6 * t2 + 4, -3 * t3 + 3 * t2 + 3 * t + 1, t3]) / 6.0
    db = np.stack([-(1 - t) ** 2, 9 * t2 - 12 * t, -9 * t2 + 6 * t + 3, 3 * t2]) / 6.0
    return b, db


def bspline_surface(heights, size=(4.0, 4.0), resolution: int = 96,
                    name: str = "bspline_surface") -> Mesh:
    """A smooth height field ``z(x, y)``: a uniform bicubic B-spline (C2 across its patches,
    like the paper's joined Bezier patches) over a grid of control heights (m, n), m, n >= 4,
    spanning ``size`` centred at the origin, tessellated ``resolution`` quads per side with
    exact analytic normals (one smooth patch class)."""
    h = np.asarray(heights, np.float64)
    m, n = h.shape
    res = max(int(resolution), 1)
    s = np.linspace(0.0, m - 3, res + 1)
    t = np.linspace(0.0, n - 3, res + 1)

    def basis(u, count):
        i = np.minimum(np.floor(u).astype(int), count - 4)
        b, db = _bspline_basis(u - i)
        return i, b, db

    iu, bu, dbu = basis(s, m)
    iv, bv, dbv = basis(t, n)
    z = np.zeros((res + 1, res + 1))
    zu = np.zeros_like(z)
    zv = np.zeros_like(z)
    for a in range(4):
        for b in range(4):
            c = h[iu[:, None] + a, iv[None, :] + b]
            z += bu[a][:, None] * bv[b][None, :] * c
            zu += dbu[a][:, None] * bv[b][None, :] * c
            zv += bu[a][:, None] * dbv[b][None, :] * c
    sx, sy = float(size[0]), float(size[1])
    X = (s / (m - 3) - 0.5) * sx
    Y = (t / (n - 3) - 0.5) * sy
    Xg, Yg = np.meshgrid(X, Y, indexing="ij")
    v = np.stack([Xg.ravel(), Yg.ravel(), z.ravel()], 1)
    # dz/dx = zu * (m - 3) / sx
    nx = -zu * (m - 3) / sx
    ny = -zv * (n - 3) / sy
    nrm = np.stack([nx.ravel(), ny.ravel(), np.ones(z.size)], 1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    idx = np.arange((res + 1) ** 2).reshape(res + 1, res + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    uv = np.stack([Xg.ravel() / sx + 0.5, Yg.ravel() / sy + 0.5], 1)
    return Mesh(name, v, f, corner_normals=nrm[f].astype(np.float32),
                corner_uvs=uv[f].astype(np.float32))


def revolve(radius, height, segments: int = 64, name: str = "revolve", closed: bool = True) -> Mesh:
    """A surface of revolution about +Z of the profile ``(radius[k], height[k])`` (bottom to
    top), smooth normals. ``closed``: the profile's ends (radius 0) become poles."""
    r = np.asarray(radius, np.float64)
    z = np.asarray(height, np.float64)
    ph = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    rings = [(k, rk, zk) for k, (rk, zk) in enumerate(zip(r, z, strict=True))]
    verts, ring_ids = [], []
    for _, rk, zk in rings:
        if rk <= 0.0:
            ring_ids.append([len(verts)] * segments)
            verts.append((0.0, 0.0, zk))
        else:
            ring_ids.append(list(range(len(verts), len(verts) + segments)))
            verts += [(rk * np.cos(p), rk * np.sin(p), zk) for p in ph]
    faces = []
    for k in range(len(rings) - 1):
        lo, hi = ring_ids[k], ring_ids[k + 1]
        for j in range(segments):
            j1 = (j + 1) % segments
            a, b, c, d = lo[j], lo[j1], hi[j], hi[j1]
            if a != b:
                faces.append((a, b, d))
            if c != d:
                faces.append((a, d, c))
    f = np.array(faces, np.int32)
    return Mesh(name, np.array(verts), f, smooth=True)
