"""Which objects get an RI-tree, the scene restricted to them, and what each tree depends
on (per-instance fingerprints: a new export drops the trees whose fingerprint changed).

Only mirror or glass objects of at least :data:`MIN_TRIANGLES` triangles without a texture
(every object of that size in the thickness view): the base tracer intersects anything
smaller, or diffuse, with one BVH ray, and nothing is left for a tree to save.
"""

from __future__ import annotations

import numpy as np

#: objects with fewer triangles are traced (cheaper than any tree)
MIN_TRIANGLES = 200

def eligible(sa, thickness_view: bool, min_triangles: int = MIN_TRIANGLES) -> np.ndarray:
    """Which instances get an RI-tree: (I,) bool (module doc)."""
    n_tri = np.diff(sa.mesh_tri_start)[sa.inst_mesh]
    out = (n_tri >= int(min_triangles)) & sa.inst_alive  # a dead slot (tombstone): no tree
    for k in np.flatnonzero(out):
        mats = sa.inst_mat[sa.inst_mat_start[k]:sa.inst_mat_start[k + 1]]
        if np.any(sa.mat_tex[mats] >= 0):
            out[k] = False
        elif not thickness_view and not np.any(
                (sa.mat_mirror[mats] > 0).any(axis=1) | (sa.mat_transmission[mats] > 0).any(
                    axis=1)):
            out[k] = False
    return out


def subset(sa, keep: np.ndarray):
    """The scene packing restricted to instances ``keep`` (ids renumbered)."""
    keep = np.asarray(keep, np.int64)
    starts = sa.inst_mat_start
    mats = [sa.inst_mat[starts[k]:starts[k + 1]] for k in keep]
    lens = np.array([len(m) for m in mats], np.int64)
    return sa._replace(
        light_recv=(np.ascontiguousarray(sa.light_recv[:, keep]) if sa.light_recv.shape[0]
                    else sa.light_recv),
        light_block=(np.ascontiguousarray(sa.light_block[:, keep]) if sa.light_block.shape[0]
                     else sa.light_block),
        inst_mesh=np.ascontiguousarray(sa.inst_mesh[keep]),
        inst_xform=np.ascontiguousarray(sa.inst_xform[keep]),
        inst_inv=np.ascontiguousarray(sa.inst_inv[keep]),
        inst_nmat=np.ascontiguousarray(sa.inst_nmat[keep]),
        inst_aabb=np.ascontiguousarray(sa.inst_aabb[keep]),
        inst_alive=np.ascontiguousarray(sa.inst_alive[keep]),
        inst_mat_start=np.concatenate([[0], np.cumsum(lens)]).astype(np.int32),
        inst_mat=(np.concatenate(mats).astype(np.int32) if len(mats)
                  else np.zeros(0, np.int32)))
