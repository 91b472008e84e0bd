"""LLVM vector operations on the 16 lanes of a compositing block (:mod:`roodi_toolkit.render.lanes`), as two halves of
8 (``@intrinsic``: portable IR, no CPU-specific instruction; LLVM lowers each half to one AVX register, or to two
of SSE or NEON), on lanes held in stack arrays or as :class:`~.simd.Vec` values: several rows' sums over the 16
lanes side by side in a fixed tree (:func:`_fold_rows`, :func:`_lane_sums_into`, :func:`_lane_dots`; as scalar code,
16 loads and 15 operations a row) and a channel's update over the 16 lanes (:func:`_lanes_axpy`,
:func:`_lanes_scale`; as a loop inside the channels' loop, LLVM ran it in its 4-lane remainder). Found by reading
the assembly of the kernels (``benchmarks/profile_kernels.py``). And, for the projection
(:mod:`.projection_kernels`), 16 Gaussians' rows read as one vector and parted into columns (:func:`_columns_into`)
and a Gaussian's SH colour and its gradients with the three channels as a vector's lanes (:func:`_sh_sums`,
:func:`_sh_weights`).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .simd import LANES, Vec, halves


def _shuffle(builder, a, b, picks):
    """LLVM's ``shufflevector``: the lanes ``picks`` of the vectors ``a`` and ``b`` laid end to end."""
    return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(ir.IntType(32), len(picks)), list(picks)))


def _load_halves(context, builder, arrty, array, start=0):
    """The 16 lanes from element ``start`` of the C-contiguous float stack array ``array`` as two LLVM vectors of 8
    (lanes 0-7 and 8-15): loaded as the vectorised loops stored them, eight at a time (one 16-wide load of two 8-wide
    stores waits for both to reach the cache: no store-to-load forwarding)."""
    ty = context.get_value_type(arrty.dtype)
    data = context.make_array(arrty)(context, builder, array).data
    vty = ir.VectorType(ty, LANES // 2)
    align = arrty.dtype.bitwidth // 8
    return tuple(builder.load(builder.bitcast(builder.gep(data, [ir.Constant(ir.IntType(64), start + at)]),
                                              vty.as_pointer()), align=align) for at in (0, LANES // 2))


def _is_lanes(v):
    """A block's 16 float lanes in a 1-D C-contiguous stack array."""
    return isinstance(v, types.Array) and isinstance(v.dtype, types.Float) and v.ndim == 1 and v.layout == "C"


def _lanes_in(v):
    """A block's 16 float lanes to read: a stack array (:func:`_is_lanes`) or a :class:`~.simd.Vec`."""
    return _is_lanes(v) or (isinstance(v, Vec) and isinstance(v.dtype, types.Float))


def _lanes_halves(context, builder, ty, value):
    """The 16 lanes of ``value`` (:func:`_lanes_in`) as two LLVM vectors of 8."""
    if isinstance(ty, Vec):
        return halves(builder, value)
    return _load_halves(context, builder, ty, value)


def _store_halves(context, builder, arrty, array, halves):
    """Store LLVM vectors of 8 one after the other from the start of the 1-D C-contiguous stack array ``array``: two
    halves fill its 16 lanes (as :func:`_load_halves` loads them), more fill more (:func:`_lane_dots`)."""
    data = context.make_array(arrty)(context, builder, array).data
    align = arrty.dtype.bitwidth // 8
    for g, vec in enumerate(halves):
        ptr = builder.bitcast(builder.gep(data, [ir.Constant(ir.IntType(64), g * (LANES // 2))]), vec.type.as_pointer())
        builder.store(vec, ptr, align=align)


def _broadcast(builder, value):
    """An LLVM vector of 8 copies of the scalar ``value``."""
    return _splat_n(builder, value, LANES // 2)


@intrinsic
def _lanes_axpy(typingctx, y, x, a):  # pragma: no cover - compiled
    """``y[q] += x[q] * a`` for the 16 lanes (a multiplication, then an addition: the values of the loop written
    out), as two 8-lane LLVM vector operations: the channel loops of the compositing wrote this as a loop over the
    lanes inside the loop over the channels, which LLVM vectorised 32 lanes at a time and so ran in its 4-lane
    remainder."""
    if not (_is_lanes(y) and _is_lanes(x) and y.dtype == x.dtype and a == y.dtype):
        return None

    def codegen(context, builder, signature, args):
        ty_y, ty_x, _ = signature.args
        ys = _load_halves(context, builder, ty_y, args[0])
        xs = _load_halves(context, builder, ty_x, args[1])
        av = _broadcast(builder, args[2])
        _store_halves(context, builder, ty_y, args[0],
                      [builder.fadd(yv, builder.fmul(xv, av)) for yv, xv in zip(ys, xs)])
        return context.get_dummy_value()

    return types.none(y, x, a), codegen


@intrinsic
def _lanes_scale(typingctx, y, x, a):  # pragma: no cover - compiled
    """``y[q] = x[q] * a`` for the 16 lanes, as two 8-lane LLVM vector operations: a sum over channels starts with it
    instead of 16 zeros, which a loop stored one lane at a time and the next vector load then waited for."""
    if not (_is_lanes(y) and _is_lanes(x) and y.dtype == x.dtype and a == y.dtype):
        return None

    def codegen(context, builder, signature, args):
        ty_y, ty_x, _ = signature.args
        xs = _load_halves(context, builder, ty_x, args[1])
        av = _broadcast(builder, args[2])
        _store_halves(context, builder, ty_y, args[0], [builder.fmul(xv, av) for xv in xs])
        return context.get_dummy_value()

    return types.none(y, x, a), codegen


def _count(size):
    """How many rows a multiple-sum intrinsic adds up: an integer literal, or ``4 * G`` for a tuple of ``G`` channel
    groups (as :func:`_stack_empty`); None for anything else."""
    if isinstance(size, types.IntegerLiteral):
        return size.literal_value
    if isinstance(size, types.BaseTuple):
        return 4 * len(size)
    return None


def _fold_rows(builder, rows):
    """The sums of ``rows`` (each 16 lanes as two vectors of 8) in the kernels' fixed tree (lane ``q`` with lane ``q +
    8``, then the first four of those with the last four, two with two, one with one), all at once: each step adds
    the lanes of two rows laid side by side in one vector (``shufflevector``), so eight sums take the additions and
    shuffles that one row's tree alone spends on three. Returns vectors of 8 sums, rows ``8 g`` to ``8 g + 7`` in vector
    ``g`` (an odd row out is paired with itself; its copy lands past the last row)."""
    level = [builder.fadd(lo, hi) for lo, hi in rows]  # lane q with lane q + 8
    for picks in (([0, 1, 2, 3, 8, 9, 10, 11], [4, 5, 6, 7, 12, 13, 14, 15]),  # first four with last four
                  ([0, 1, 4, 5, 8, 9, 12, 13], [2, 3, 6, 7, 10, 11, 14, 15]),  # two with two
                  ([0, 2, 4, 6, 8, 10, 12, 14], [1, 3, 5, 7, 9, 11, 13, 15])):  # one with one
        pairs = [(level[i], level[min(i + 1, len(level) - 1)]) for i in range(0, len(level), 2)]
        level = [builder.fadd(_shuffle(builder, a, b, picks[0]), _shuffle(builder, a, b, picks[1])) for a, b in pairs]
    return level


def _is_rows(v):
    """A C-contiguous 2-D float array (rows of 16 lanes on the stack, or a destination of sums)."""
    return isinstance(v, types.Array) and isinstance(v.dtype, types.Float) and v.ndim == 2 and v.layout == "C"


def _rows_in(v):
    """Rows of 16 float lanes to read: a [K, 16] stack array (:func:`_is_rows`) or a tuple of
    :class:`~.simd.Vec`."""
    if isinstance(v, types.UniTuple):
        return isinstance(v.dtype, Vec) and isinstance(v.dtype.dtype, types.Float)
    return _is_rows(v)


def _dtype(v):
    """The element type of lanes or rows (:func:`_lanes_in`, :func:`_rows_in`)."""
    return v.dtype.dtype if isinstance(v, types.UniTuple) else v.dtype


def _rows(context, builder, rowsty, rows, k):
    """The rows ``0:k`` of ``rows`` (:func:`_rows_in`), each as two LLVM vectors of 8."""
    if isinstance(rowsty, types.UniTuple):
        return [halves(builder, builder.extract_value(rows, r)) for r in range(k)]
    return [_load_halves(context, builder, rowsty, rows, r * LANES) for r in range(k)]


def _products(context, builder, xty, x, rowsty, rows, k):
    """``x[q] * rows[r, q]`` for the rows ``0:k``, each as two LLVM vectors of 8."""
    xs = _lanes_halves(context, builder, xty, x)
    return [tuple(builder.fmul(xv, rv) for xv, rv in zip(xs, row)) for row in _rows(context, builder, rowsty, rows, k)]


@intrinsic
def _lane_dots(typingctx, x, rows, count, out):  # pragma: no cover - compiled
    """Write into ``out`` (a 1-D stack array with room for ``count`` rounded up to a multiple of 8) the sums over the
    16 lanes of ``x[q] * rows[k, q]`` for the rows ``0:count`` (as :func:`_lane_sums_into`): the products, then their
    sums in :func:`_fold_rows`' tree."""
    k = _count(count)
    if not (k and _lanes_in(x) and _rows_in(rows) and _is_lanes(out) and x.dtype == _dtype(rows) == out.dtype):
        return None

    def codegen(context, builder, signature, args):
        products = _products(context, builder, signature.args[0], args[0], signature.args[1], args[1], k)
        _store_halves(context, builder, signature.args[3], args[3], _fold_rows(builder, products))
        return context.get_dummy_value()

    return types.none(x, rows, count, out), codegen


def _add_into_row(context, builder, dstty, dst, row, vectors, k):
    """Add the first ``k`` sums of :func:`_fold_rows`' ``vectors`` (sum ``r`` in lane ``r % 8`` of vector ``r // 8``)
    into ``dst[row, 0:k]`` (a C-contiguous float array of at least ``k`` columns), four, then two, then one at a time
    as vector loads, additions and stores: each sum is added to its element as one scalar addition would."""
    arr = context.make_array(dstty)(context, builder, dst)
    ty = context.get_value_type(dstty.dtype)
    stride = builder.extract_value(arr.strides, 0)
    base = builder.gep(builder.bitcast(arr.data, ir.IntType(8).as_pointer()), [builder.mul(row, stride)])
    base = builder.bitcast(base, ty.as_pointer())
    align = dstty.dtype.bitwidth // 8
    at = 0
    for width in (4, 2, 1):
        while k - at >= width:
            lanes = [(at + i) % (LANES // 2) for i in range(width)]
            vec = vectors[at // (LANES // 2)]  # a chunk of 4 never straddles two vectors of 8: at is a multiple of 4
            part = _shuffle(builder, vec, vec, lanes) if width > 1 else builder.extract_element(
                vec, ir.Constant(ir.IntType(32), lanes[0]))
            ptr = builder.gep(base, [ir.Constant(ir.IntType(64), at)])
            if width > 1:
                ptr = builder.bitcast(ptr, part.type.as_pointer())
            builder.store(builder.fadd(builder.load(ptr, align=align), part), ptr, align=align)
            at += width


@intrinsic
def _lane_sums_into(typingctx, rows, count, dst, row):  # pragma: no cover - compiled
    """Add the sums of the 16 lanes of each of the rows ``0:count`` of ``rows`` (a C-contiguous [K, 16] stack array;
    ``count`` an integer literal or a tuple of channel groups, :func:`_count`), each in :func:`_fold_rows`' tree order,
    into ``dst[row, 0:count]`` (a C-contiguous 2-D float array of the rows' dtype with at least ``count`` columns),
    without storing them first: a sum stored as a vector and read back as a scalar waited for the store to reach the
    cache (the hottest instructions of the backward's profile). The rows' sums are made side by side
    (:func:`_fold_rows`), each equal to its row's sum alone bit for bit; summed one by one, the backward's six
    gradients of a pair took a tree of four steps each, then an extraction."""
    k = _count(count)
    if not (k and _rows_in(rows) and _is_rows(dst) and dst.dtype == _dtype(rows) and isinstance(row, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        row64 = context.cast(builder, args[3], signature.args[3], types.intp)
        sums = _fold_rows(builder, _rows(context, builder, signature.args[0], args[0], k))
        _add_into_row(context, builder, signature.args[2], args[2], row64, sums, k)
        return context.get_dummy_value()

    return types.none(rows, count, dst, row), codegen


@intrinsic
def _lane_dots_into(typingctx, x, rows, count, dst, row):  # pragma: no cover - compiled
    """Add the sums of :func:`_lane_dots` into ``dst[row, 0:count]`` (as :func:`_lane_sums_into`), without storing
    them first."""
    k = _count(count)
    if not (k and _lanes_in(x) and _rows_in(rows) and _is_rows(dst) and x.dtype == _dtype(rows) == dst.dtype
            and isinstance(row, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        products = _products(context, builder, signature.args[0], args[0], signature.args[1], args[1], k)
        row64 = context.cast(builder, args[4], signature.args[4], types.intp)
        _add_into_row(context, builder, signature.args[3], args[3], row64, _fold_rows(builder, products), k)
        return context.get_dummy_value()

    return types.none(x, rows, count, dst, row), codegen


@intrinsic
def _columns_into(typingctx, dst, row, src, first, count):  # pragma: no cover - compiled
    """Write ``src[first + l, c]`` into ``dst[row + c, l]`` for the 16 rows ``l`` and the ``count`` (an integer
    literal) columns ``c`` of the C-contiguous 2-D float array ``src`` whose rows are ``count`` long, converted to the
    dtype of ``dst`` (a C-contiguous [K, 16] float stack array): the 16 rows as one vector load of ``16 count``
    numbers, parted into columns by shuffles. A loop over the 16 rows became AVX-512 gathers, which this AMD CPU runs
    as 16 loads one after the other (a tenth of the projection's samples). No bounds check."""
    k = count.literal_value if isinstance(count, types.IntegerLiteral) else 0
    if not (k and _is_rows(dst) and isinstance(src, types.Array) and src.ndim == 2 and src.layout == "C"
            and isinstance(src.dtype, types.Float) and src.dtype.bitwidth <= dst.dtype.bitwidth
            and isinstance(row, types.Integer) and isinstance(first, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        sty, dty = context.get_value_type(src.dtype), context.get_value_type(dst.dtype)
        start = builder.mul(context.cast(builder, args[3], signature.args[3], types.intp), ir.Constant(i64, k))
        sdata = context.make_array(signature.args[2])(context, builder, args[2]).data
        ptr = builder.bitcast(builder.gep(sdata, [start]), ir.VectorType(sty, LANES * k).as_pointer())
        block = builder.load(ptr, align=src.dtype.bitwidth // 8)
        ddata = context.make_array(signature.args[0])(context, builder, args[0]).data
        base = builder.mul(context.cast(builder, args[1], signature.args[1], types.intp), ir.Constant(i64, LANES))
        for c in range(k):
            col = _shuffle(builder, block, block, [c + k * q for q in range(LANES)])
            if dty != sty:
                col = builder.fpext(col, ir.VectorType(dty, LANES))
            at = builder.gep(ddata, [builder.add(base, ir.Constant(i64, c * LANES))])
            builder.store(col, builder.bitcast(at, col.type.as_pointer()), align=dst.dtype.bitwidth // 8)
        return context.get_dummy_value()

    return types.none(dst, row, src, first, count), codegen


def _row_vector(context, builder, arrty, array, index, count):
    """A pointer to the first ``count`` elements of row ``index`` (intp) of the array ``array`` (its first stride), as
    one LLVM vector of its dtype."""
    arr = context.make_array(arrty)(context, builder, array)
    ptr = builder.gep(builder.bitcast(arr.data, ir.IntType(8).as_pointer()),
                      [builder.mul(index, builder.extract_value(arr.strides, 0))])
    return builder.bitcast(ptr, ir.VectorType(context.get_value_type(arrty.dtype), count).as_pointer())


@intrinsic
def _sh_sums(typingctx, basis, sh, i, count, start):  # pragma: no cover - compiled
    """The three channels' sums ``start + basis[0] sh[i, 0, c] + ... + basis[count - 1] sh[i, count - 1, c]``
    (``count`` an integer literal; ``sh`` a C-contiguous [N, K, 3] float array, K >= ``count``; ``basis`` a 1-D
    float stack array of the sums' dtype) as a tuple of three, each added base after base in that order with a
    product and a sum, as the scalar loop does (the same bits): the Gaussian's ``3 count`` coefficients are one
    vector load, converted to the basis' dtype at once, and the three channels are the lanes of one vector, so a base
    costs a shuffle, a product and a sum where the scalar loop spent three loads, conversions, products and sums."""
    k = count.literal_value if isinstance(count, types.IntegerLiteral) else 0
    if not (k and _is_lanes(basis) and isinstance(sh, types.Array) and sh.ndim == 3 and sh.layout == "C"
            and isinstance(sh.dtype, types.Float) and sh.dtype.bitwidth <= basis.dtype.bitwidth
            and isinstance(i, types.Integer) and start == basis.dtype):
        return None
    ret = types.UniTuple(basis.dtype, 3)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        sty, dty = context.get_value_type(sh.dtype), context.get_value_type(basis.dtype)
        index = context.cast(builder, args[2], signature.args[2], types.intp)
        coeffs = builder.load(_row_vector(context, builder, signature.args[1], args[1], index, 3 * k),
                              align=sh.dtype.bitwidth // 8)
        if dty != sty:
            coeffs = builder.fpext(coeffs, ir.VectorType(dty, 3 * k))
        bdata = context.make_array(signature.args[0])(context, builder, args[0]).data
        sums = _splat_n(builder, args[4], 4)
        for b in range(k):
            bk = builder.load(builder.gep(bdata, [ir.Constant(i64, b)]))
            part = _shuffle(builder, coeffs, coeffs, [3 * b, 3 * b + 1, 3 * b + 2, 3 * b])
            sums = builder.fadd(sums, builder.fmul(_splat_n(builder, bk, 4), part))
        return context.make_tuple(builder, ret, [builder.extract_element(sums, ir.Constant(ir.IntType(32), c))
                                                 for c in range(3)])

    return ret(basis, sh, i, count, start), codegen


@intrinsic
def _sh_weights(typingctx, basis, sh, g_sh, i, count, g0, g1, g2):  # pragma: no cover - compiled
    """The SH backward's products of one Gaussian for ``count`` bases (an integer literal): writes ``g_sh[i, b, c] =
    basis[b] g_c`` and returns the 16 weights ``w_b = (g0 sh[i, b, 0] + g1 sh[i, b, 1]) + g2 sh[i, b, 2]`` (0 past
    ``count``), whose sum with the bases' derivatives is the direction's gradient: the scalar loop's operations (the
    same bits) on vectors of the ``count`` bases, the row of coefficients one vector load parted into its three
    channels by shuffles, the row of gradients put together by shuffles and stored as one vector (``sh`` and ``g_sh``
    C-contiguous [N, K, 3] of one float dtype, K >= ``count``; ``basis`` a 1-D stack array and the ``g`` of the
    products' dtype; the bases are read one by one, as they were stored)."""
    k = count.literal_value if isinstance(count, types.IntegerLiteral) else 0
    if not (k and _is_lanes(basis) and isinstance(sh, types.Array) and sh.ndim == 3 and sh.layout == "C"
            and isinstance(sh.dtype, types.Float) and g_sh == sh and sh.dtype.bitwidth <= basis.dtype.bitwidth
            and isinstance(i, types.Integer) and g0 == g1 == g2 == basis.dtype):
        return None
    ret = types.UniTuple(basis.dtype, LANES)

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        sty, dty = context.get_value_type(sh.dtype), context.get_value_type(basis.dtype)
        index = context.cast(builder, args[3], signature.args[3], types.intp)

        def row_ptr(at):
            return _row_vector(context, builder, signature.args[at], args[at], index, 3 * k)

        coeffs = builder.load(row_ptr(1), align=sh.dtype.bitwidth // 8)
        wide = ir.VectorType(dty, k)
        chans = []
        for c in range(3):
            part = _shuffle(builder, coeffs, coeffs, [c + 3 * b for b in range(k)])
            chans.append(builder.fpext(part, wide) if dty != sty else part)
        gs = [_splat_n(builder, args[5 + c], k) for c in range(3)]
        w = builder.fadd(builder.fadd(builder.fmul(gs[0], chans[0]), builder.fmul(gs[1], chans[1])),
                         builder.fmul(gs[2], chans[2]))
        bdata = context.make_array(signature.args[0])(context, builder, args[0]).data
        bv = ir.Constant(wide, ir.Undefined)
        for b in range(k):
            bv = builder.insert_element(bv, builder.load(builder.gep(bdata, [ir.Constant(ir.IntType(64), b)])),
                                        ir.Constant(i32, b))
        own = [builder.fmul(bv, gs[c]) for c in range(3)]
        if dty != sty:
            own = [builder.fptrunc(v, ir.VectorType(sty, k)) for v in own]
        pair = _shuffle(builder, own[0], own[1], list(range(2 * k)))
        third = _shuffle(builder, own[2], own[2], list(range(k)) * 2)
        grads = _shuffle(builder, pair, third, [c * k + b for b in range(k) for c in range(3)])
        builder.store(grads, row_ptr(2), align=sh.dtype.bitwidth // 8)
        zero = ir.Constant(dty, 0.0)
        return context.make_tuple(builder, ret, [builder.extract_element(w, ir.Constant(i32, b)) if b < k else zero
                                                 for b in range(LANES)])

    return ret(basis, sh, g_sh, i, count, g0, g1, g2), codegen


def _splat_n(builder, value, n):
    """An LLVM vector of ``n`` copies of the scalar ``value``."""
    vec = builder.insert_element(ir.Constant(ir.VectorType(value.type, n), ir.Undefined), value,
                                 ir.Constant(ir.IntType(32), 0))
    return _shuffle(builder, vec, vec, [0] * n)
