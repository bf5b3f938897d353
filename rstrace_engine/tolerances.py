"""Every numerical tolerance rstrace uses, in one place.

Ray math is float64. Offsets that move a spawned ray off its surface scale with the
magnitude of the coordinates involved (never a fixed 1e-4), so a scene renders the same
at 1e-4 and at 1e5 scale, or translated by 1e6.
"""

#: Relative size of the self-intersection offset: a ray spawned at point p starts at
#: ``p + n * offset`` with ``offset = SPAWN_OFFSET_REL * max(|p|_inf, scene_extent *
#: SPAWN_OFFSET_EXTENT_FRAC)``. Float64 keeps ~16 digits; 1e-11 leaves ~5 digits of headroom
#: for the hit-point error. Not larger: 1e-9 is 1 cm at 1e7 from the origin, where shadow
#: rays would start past the 4 cm gaps between stacked objects and light would leak.
SPAWN_OFFSET_REL = 1e-11

#: Float32 accelerators (Embree) skip hits closer than this fraction of the scene's (and the
#: ray origin's) coordinate magnitude: about 16 float32 ulps, past the rounding of float32
#: vertices and origins, so a ray spawned off a surface never hits that surface again.
FLOAT32_TNEAR_REL = 2e-6

#: Float32 accelerators (Embree) cannot order hits on different objects closer than this
#: fraction of the scene's (and the ray origin's) coordinate magnitude (coplanar or touching
#: faces: an object resting on a floor): which one Embree reports then depends on its BVH,
#: i.e. on every other object in the scene. Objects whose box holds the reported hit point
#: (padded by twice this) are re-tested in a window of this half-width around the hit and
#: the closest float64 hit wins (ties: the highest instance id, as the brute-force oracle).
FLOAT32_TIE_REL = 2e-6

#: The Principled-like GGX lobe lights nothing below this alpha (roughness 0.05): a point
#: light's highlight on a near mirror is a sub-pixel spike (Cycles shows none at roughness 0);
#: such surfaces reflect through mirror rays.
GLOSSY_ALPHA_MIN = 0.0025

#: Relative rounding of a float32 input (2^-23, one ulp, with room): limits on settings that
#: Blender stores in float32 accept values this close to them.
FLOAT32_INPUT_REL = 2.0 ** -22

#: Shadow rays stop this fraction short of the light (relative to their length).
SHADOW_END_REL = 1e-9

#: A triangle whose doubled area is below ``DEGENERATE_AREA_REL * longest_edge**2`` is
#: dropped at scene build (counted in the stats).
DEGENERATE_AREA_REL = 1e-12

#: A world matrix whose |det| is below ``SINGULAR_DET_REL * (column norms product)`` is
#: rejected as singular (zero scale on some axis).
SINGULAR_DET_REL = 1e-12

#: Normals shorter than this (after interpolation) fall back to the geometric normal.
NORMAL_MIN_LENGTH = 1e-12

#: Radiance values above this are treated as a sign of broken input (NaN/Inf guard).
RADIANCE_MAX = 1e30

#: Largest coordinate magnitude accepted in scene input (beyond this float64 ray math
#: loses the precision the offsets rely on).
COORD_MAX = 1e12

#: The spawn offset never drops below this fraction of the scene extent times
#: ``SPAWN_OFFSET_REL`` (points near the origin of a large scene still get a usable offset).
SPAWN_OFFSET_EXTENT_FRAC = 1e-3

#: A reflection/refraction ray whose path weight (largest RGB channel of the product of
#: reflectances along its path) is below this is not spawned: its contribution is invisible.
PATH_WEIGHT_MIN = 1e-8

#: Russian roulette of a deeper rough bounce's rays (``tracing.glossy_rays.roulette``): a
#: ray carrying a fraction ``r`` of its point's path weight below this goes on with
#: probability ``r / GLOSSY_ROULETTE_REL``, its weight divided by that (so a survivor
#: carries this fraction of the point's weight); measured in docs/glossy.md (session 33)
GLOSSY_ROULETTE_REL = 0.25

#: Ray/box slab test: the exit distance is scaled by ``1 + 2 * gamma(3)`` for float64
#: (pbrt-v4, section 6.8.2) so rounding never makes a ray miss a box it touches.
BOX_TFAR_SCALE = 1.0 + 2.0 * (3.0 * 2.0**-53) / (1.0 - 3.0 * 2.0**-53)

#: BVH nodes are culled only when entered beyond the best hit so far by more than this
#: fraction of its distance (64 float64 ulps): a box entry and a triangle distance round
#: differently, and culling a node by an ulp lost a hit that ties the best within an ulp
#: (two objects' coplanar faces), so which one was reported depended on the traversal order.
BVH_CULL_REL = 64.0 * 2.0**-53

#: Instance world boxes in the top-level BVH are padded by this fraction of their magnitude
#: (the world -> object transform of a ray and of the box corners both round).
INSTANCE_BOX_PAD_REL = 1e-9

#: Input checks: a world matrix's bottom row may differ from (0, 0, 0, 1) by this much (the
#: host's float32 matrices) ...
MATRIX_AFFINE_ATOL = 1e-9
#: ... and a material's energy shares (diffuse + specular + mirror + transmission, per
#: channel) may sum past 1 by this much.
MATERIAL_SUM_SLACK = 1e-6
#: ``shapes.look_at``: an up vector this nearly along the view direction (the length of
#: their cross product) is replaced by the y axis.
LOOK_AT_PARALLEL = 1e-12

#: GGX: the directional albedo is computed at no more grazing a cosine than this ...
GGX_COS_MIN = 1e-4
#: ... and the multiple-scattering compensation ``(1 - E) / E`` divides by at least this.
GGX_ALBEDO_MIN = 1e-3

# ----------------------------------------------------------------------------- interpolants

#: Linetree boxes: every object's world box is padded on each side by this fraction of the
#: scene extent (a flat object still gets a box of positive thickness) ...
LINETREE_PAD_SCENE_REL = 1e-3
#: ... plus this fraction of the object's own diagonal.
LINETREE_PAD_OBJECT_REL = 1e-3

#: Surface classes: adjacent triangles belong to one smooth patch when their per-corner
#: shading normals at the shared vertices differ by less than this (unit vectors) ...
CLASS_NORMAL_TOL = 1e-5
#: ... and their uvs there differ by less than this.
CLASS_UV_TOL = 1e-6
#: A mesh is convex when no vertex lies more than this fraction of its diagonal in front of
#: any triangle's plane.
CONVEX_TOL_REL = 1e-9
#: Facing tests of the error predicate (triangle normal against a line direction or the
#: direction to a light) count as decided only beyond this fraction of the product of
#: lengths; nearer to zero they count as both (the conservative side).
FACING_EPS_REL = 1e-12
#: Tunnel and deeper-level shafts pad the boxes of their 16 end points by this fraction of
#: the boxes' diagonal (secondary hit points of interior lines are not bounded exactly).
TUNNEL_MARGIN_REL = 0.05
#: Shaft planes are moved outward by this fraction of the scene's coordinate magnitude
#: (extent + largest |coordinate|), so rounding never lets a touching triangle escape.
SHAFT_SLACK_REL = 1e-9
#: Boxes computed in float64 (a shaft's box taken to object space, a slab's box) grow by
#: this fraction of their coordinates' magnitude, past the rounding of the computation.
BOX_ROUND_REL = 1e-12
#: Spot cones: the range of cosines a box spans is widened by this much (acos, asin and cos
#: round).
CONE_COS_SLACK = 1e-12
#: A slab's certified depth range is padded by this fraction of its face pair's depth, past
#: its width margin (rounding never leaves a crossing just outside it).
SLAB_DEPTH_PAD_REL = 1e-9
#: Ray segment trees: slack of the 5D interval tests, relative to the coordinates (rounding
#: never hides an overlap).
RST_SLACK = 1e-9
#: Textured samples: relative tolerance of the affine check ``|R + texel D - L|``.
TEX_SPLIT_REL = 1e-9

#: Occluder coverage (:mod:`.interpolants.occluders`): a plane separates the cell from the
#: light only beyond this fraction of the coordinates' magnitude (plus the shaft slack), and
#: a sun lies in the plane below it ...
COVER_PLANE_REL = 1e-9
#: ... triangles count as facing the plane's way, and their clipped areas as summing to the
#: projection's area (no overlap), within this fraction.
COVER_AREA_REL = 1e3 * COVER_PLANE_REL
#: A convex occluder's corner segment tests count a crossing only this far inside a
#: triangle (barycentric) and inside the segment (parameter, at both ends).
COVER_BARY_MARGIN = 1e-9
COVER_T_MARGIN = 1e-6
#: The convex hull of the projected corners sorts them by x, ties by y through this weight.
HULL_ORDER_TIE = 1e-12

#: Ray segment trees: their domain (the scene box with its point and spot lights) is padded
#: by this fraction of its diagonal ...
RST_DOMAIN_PAD_REL = 0.01
#: ... plus this fraction of ``1 + `` its largest coordinate magnitude (a flat or tiny scene
#: still gets a domain of positive size).
RST_DOMAIN_PAD_MAG = 1e-6

# ----------------------------------------------------------------------------- per-pixel records

#: Angular error bound (radians) of the records' octahedral direction encoding (16 + 16 bits):
#: a miss's stored direction is widened into a cone this wide.
RECORD_DIR_ERROR = 2e-4
#: Edited regions are grown by this fraction of the scene's coordinate magnitude (plus half
#: the points' quantisation step) to cover spawn offsets and rounding.
RECORD_SLACK_REL = 1e-6

#: Re-shaded soft samples' rays against one edited object (:mod:`~.tracing.object_rays`):
#: its vertices' sphere is grown, and the ball its closed surface holds shrunk, by this
#: fraction of that sphere's radius -- the least angle a proven ray crosses a triangle at
#: is half of it, ~10^10 times the rounding of the watertight test ...
SOLID_BALL_REL = 1e-6
#: ... and each ray's distance to the centre is trusted to this fraction of its object-space
#: coordinates' magnitude (its origin's distance plus the length to its closest point):
#: the world -> object transform rounds in proportion to them.
SOLID_RAY_SLACK_REL = 1e-12
#: The records' query proves a blocked soft sample stays blocked by a placed object's ball
#: (:mod:`~.tracing.sample_proofs`) trusting lengths to this fraction of the coordinates'
#: magnitude (the world balls shrunk and grown by it too): far above the rounding of the
#: world -> object transform and of the tests, far below the records' own margins.
PLACED_SLACK_REL = 1e-9

# ----------------------------------------------------------------------------- visibility field

#: Visibility field: triangles are scan-converted into tiles with their projection grown by
#: this fraction of the scene's coordinate magnitude (largest |coordinate| + extent), rays
#: are projected with the same margin, and the depth bounds used to skip and stop along a
#: beam are widened by it: the world -> object transform of a ray and the object -> world
#: transform of a triangle both round, so a hit may lie a few ulps off the world triangle.
VF_PAD_REL = 1e-9
#: Nearest-direction look-up: extra angle (radians) added to each look-up cell's radius, so
#: rounding of the corners, centres and the query's barycentrics never drops the nearest.
DIRECTION_LOOKUP_MARGIN = 1e-9

# ----------------------------------------------------------------------------- RI-tree

#: Rays spawned from an *interpolated* hit on an object (shadow, reflection and exit rays)
#: ignore that object's own surface closer than this fraction of its box diagonal: the
#: interpolated point lies off the mesh by the interpolation error, far more than the
#: spawn offset.
RI_SELF_OFFSET_REL = 2e-3
#: Thickness walks step past each crossing by this fraction of the object's diagonal.
THICKNESS_STEP_REL = 1e-9
#: An interpolated shading normal that leans past the view ray is bent back until it faces
#: the viewer by this much (cosine).
INTERP_NORMAL_BEND = 1e-6


# ----------------------------------------------------------------------------- soft lights

#: An area light's axis may deviate this much (cosine) from orthogonal to its direction
#: before it is refused; within it the axis is made exactly orthogonal.
AREA_AXIS_COS_MAX = 1e-3
#: Spreads below 0.1 degrees are taken as 0.1 degrees (Cycles clamps alike: a smaller
#: angle's attenuation vanishes in float precision).
AREA_SPREAD_MIN = 0.1 * 3.141592653589793 / 180.0
#: A light radius (m) or a sun angle (radians) below this is taken as 0: a point light or a
#: parallel sun (the radiance over so small an extent, ~ power / radius^2, would overflow).
LIGHT_EXTENT_MIN = 1e-12

#: A light's direction or area axis this close to unit length (and the axis to orthogonal)
#: is kept as given (:func:`~.geometry.lights.checked_light`): normalising again would
#: change its last bits, so a light given back with only its power changed would count as
#: moved (and be shaded again).
UNIT_SLACK = 4e-16

#: The smallest half-size of an automatic texture space along an axis (Blender's
#: ``BKE_mesh_texspace_calc``: a thinner non-zero extent is widened to it; a zero one is 1),
#: so Generated texture coordinates never divide by (nearly) zero.
TEXSPACE_HALF_MIN = 1e-5

#: Shadow linking (:mod:`~.tracing.light_linking`): a shadow ray that meets an object that
#: does not cast the light's shadow goes on from just past that hit, ``t (1 + LINK_SKIP_REL)
#: + LINK_SKIP_REL`` (unit directions), for at most ``LINK_MAX_SKIPS`` such objects.
LINK_SKIP_REL = 1e-9
LINK_MAX_SKIPS = 64

#: A spot's world frame whose axes agree in length and are orthogonal to this relative
#: slack is a round cone (:func:`~.geometry.lights.checked_light`): Blender's float32
#: matrices of a rotated, uniformly scaled spot differ by ~1e-7.
SPOT_FRAME_SLACK = 1e-6

#: Base-mode shadow-ray skips (:mod:`~.tracing.shaft_skip`): a triangle is behind a shading
#: point's own plane when its vertices lie behind the plane through the shadow-ray origin
#: by this fraction of the point's shadow-ray offset (``SPAWN_OFFSET_REL``): a traced sample
#: leaves that plane, so half the offset stays between it and the triangle, ~10^4 times
#: the rounding of the watertight ray-triangle test.
SKIP_SELF_MARGIN_FRAC = 0.5
#: ... and a group skips its own instance's triangles altogether
#: (:func:`~.tracing.shaft_skip.own_clear`) where its mesh is certified convex
#: (:func:`~.tracing.object_rays.convexity`: ``CONVEX_TOL_REL``) and a bound puts every
#: vertex behind the point's plane; the bound trusts coordinates, lengths and a triangle's
#: normal to this fraction of their magnitude (~90 ulps: above the rounding of the float64
#: transforms and cross products, ~10^3 times below the half offset it must stay under).
CONVEX_ROUND_REL = 1e-14

#: The RI_TREE continuation check (:mod:`~.ri_tree.recheck`) keys only the ray-tree nodes
#: whose path weight (largest channel) is at least this: a deeper, dimmer node that meets
#: something else changes its sample by at most its weight times the radiance it finds
#: (paths bouncing inside glass scatter at sub-pixel scale and would flag nearly every
#: pixel behind it). Chosen by measuring (docs/RI_TREE.md).
RI_RECHECK_WEIGHT = 0.01
