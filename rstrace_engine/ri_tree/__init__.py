"""The RI-tree (seed 004, Atalay & Mount): per-object 4D kd-trees interpolating geometric
attributes of rays (hit point, normals, the exit ray through mirrors and glass, thickness).

Modules, one concept each (import order: kdtree, thickness < sampling < patches < cache <
render; candidates, eligibility, fallback and surfaces serve render alone):

* :mod:`.kdtree` -- the node and sample pools of the kd-trees, splits, LRU pruning.
* :mod:`.thickness` -- the thickness view (distance travelled inside objects), exact; its
  walk also measures the samples' thickness.
* :mod:`.sampling` -- tracing the geometric attributes of sample lines against one object,
  the exit ray through glass with every internal refraction and total internal reflection.
* :mod:`.patches` -- patch equivalence classes of the corner samples, the angular threshold,
  the masked quadrilinear interpolation.
* :mod:`.cache` -- :class:`~.cache.RITreeCache`: lazy demand-driven subdivision and queries.
* :mod:`.candidates` -- which trees a ray batch queries, and the nearest answer.
* :mod:`.eligibility` -- which objects get a tree, and what each tree depends on.
* :mod:`.fallback` -- tracing an object whose tree does not pay.
* :mod:`.surfaces` -- the shading arrays of interpolated hits.
* :mod:`.render` -- :class:`~.render.RITreeRenderer`: the RI_TREE mode's frames.
"""
