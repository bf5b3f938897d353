"""The slab test of a 4-wide BVH node's four boxes at once, as LLVM vector code.

numba compiles the traversal's box tests as scalar code (its SLP vectoriser is off, and a
lane loop it does vectorise pays for runtime checks), so a node visit cost four times the
arithmetic of one box. :func:`lanes4` is a numba intrinsic that emits the test of all four
lanes on ``<4 x double>`` vectors: a node's SoA row (:mod:`.bvh`: ``lo x[4], lo y[4], ...``)
is read as six 4-wide loads (float32 boxes widened to float64 exactly), and each step is the
scalar test's own IEEE operation on four values (``fsub``, ``fmul``, ordered compares and
selects: the same bits as :func:`numba`'s ``max`` / ``min`` of two floats, no fused or
reassociated arithmetic), so every entry distance is the scalar test's, bit for bit.
(A portable build legalises the vectors to SSE2's two lanes.)
"""

from __future__ import annotations

from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

from .. import tolerances as tol

#: Offsets of the far planes in a node row: ``hi x`` at ``12 - near x``, ``hi y`` at
#: ``20 - near y``, ``hi z`` at ``28 - near z`` (near offsets from :func:`.bvh._near`).
_FAR = (12, 20, 28)


def _splat(builder, x, vt):
    """``x`` in every lane of the vector type ``vt``."""
    i32 = ir.IntType(32)
    v = builder.insert_element(ir.Constant(vt, ir.Undefined), x, ir.Constant(i32, 0))
    return builder.shuffle_vector(v, ir.Constant(vt, ir.Undefined),
                                  ir.Constant(ir.VectorType(i32, vt.count), [0] * vt.count))


@intrinsic
def lanes4(typingctx, bounds, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1):
    """Entry distances of the ray into the four boxes of row ``node`` of ``bounds`` ((N, 24)
    float32 or float64, C order): a tuple of four float64, ``inf`` where the ray misses.

    Lane ``j`` is, bit for bit::

        tn = max(max((b[nx + j] - ox) * ix, (b[ny + j] - oy) * iy),
                 max((b[nz + j] - oz) * iz, t0))
        tf = min(min((b[12 - nx + j] - ox) * ix, (b[20 - ny + j] - oy) * iy),
                 min((b[28 - nz + j] - oz) * iz, t1))
        tn if tn <= tf * BOX_TFAR_SCALE else inf

    with numba's ``max(a, b) = b if b > a else a`` and ``min(a, b) = b if b < a else a``
    (pbrt-v4's conservative slab test, :data:`~..tolerances.BOX_TFAR_SCALE`). ``nx, ny,
    nz``: the near planes' offsets (0 / 12, 4 / 16, 8 / 20 by the signs of ``ix, iy,
    iz``); ``node`` and the offsets are not wrapped (they are never negative).
    """
    if not (isinstance(bounds, types.Array) and bounds.ndim == 2 and bounds.layout == "C"
            and bounds.dtype in (types.float32, types.float64)):
        return None
    out = types.UniTuple(types.float64, 4)
    sig = out(bounds, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        f64 = ir.DoubleType()
        v4 = ir.VectorType(f64, 4)
        src = context.get_value_type(aryty.dtype)
        vsrc = ir.VectorType(src, 4)
        row = context.cast(builder, args[1], signature.args[1], types.intp)
        near = [context.cast(builder, args[k], signature.args[k], types.intp) for k in (2, 3, 4)]
        far = [builder.sub(ir.Constant(c.type, base), c) for base, c in zip(_FAR, near,
                                                                           strict=True)]
        shape = cgutils.unpack_tuple(builder, ary.shape)
        strides = cgutils.unpack_tuple(builder, ary.strides)

        def load(col):
            p = cgutils.get_item_pointer2(context, builder, ary.data, shape, strides,
                                          aryty.layout, [row, col], wraparound=False)
            v = builder.load(builder.bitcast(p, vsrc.as_pointer()), typ=vsrc,
                             align=aryty.dtype.bitwidth // 8)
            return v if src == f64 else builder.fpext(v, v4)

        org = [_splat(builder, args[k], v4) for k in (5, 6, 7)]
        inv = [_splat(builder, args[k], v4) for k in (8, 9, 10)]
        lo = [builder.fmul(builder.fsub(load(c), org[a]), inv[a]) for a, c in enumerate(near)]
        hi = [builder.fmul(builder.fsub(load(c), org[a]), inv[a]) for a, c in enumerate(far)]

        def vmax(a, b):  # numba's max(a, b)
            return builder.select(builder.fcmp_ordered(">", b, a), b, a)

        def vmin(a, b):  # numba's min(a, b)
            return builder.select(builder.fcmp_ordered("<", b, a), b, a)

        tn = vmax(vmax(lo[0], lo[1]), vmax(lo[2], _splat(builder, args[11], v4)))
        tf = vmin(vmin(hi[0], hi[1]), vmin(hi[2], _splat(builder, args[12], v4)))
        tf = builder.fmul(tf, _splat(builder, ir.Constant(f64, tol.BOX_TFAR_SCALE), v4))
        res = builder.select(builder.fcmp_ordered("<=", tn, tf), tn,
                             _splat(builder, ir.Constant(f64, float("inf")), v4))
        lanes = [builder.extract_element(res, ir.Constant(ir.IntType(32), j))
                 for j in range(4)]
        return context.make_tuple(builder, out, lanes)

    return sig, codegen
