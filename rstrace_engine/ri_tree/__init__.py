"""The RI-tree (seed 004, Atalay & Mount): per-object 4D kd-trees interpolating geometric
attributes of rays (hit point, normals, the exit ray through mirrors and glass, thickness).

Modules, one concept each (import order: kdtree < sampling < patches < cache < thickness <
render):

* :mod:`.kdtree` -- the node and sample pools of the kd-trees, splits, LRU pruning.
* :mod:`.sampling` -- tracing the geometric attributes of sample lines against one object,
  the exit ray through glass with every internal refraction and total internal reflection.
* :mod:`.patches` -- patch equivalence classes of the corner samples, the angular threshold,
  the masked quadrilinear interpolation.
* :mod:`.cache` -- :class:`~.cache.RITreeCache`: lazy demand-driven subdivision and queries.
* :mod:`.thickness` -- the thickness view (distance travelled inside objects), exact.
* :mod:`.render` -- :class:`~.render.RITreeRenderer`: the RI_TREE mode's frames.
"""
