"""A 4x4 block's 16 pixels as one value of the compiled kernels: :class:`Vec` (16 numbers of one dtype, an LLVM
``<16 x float>``, ``<16 x double>`` or ``<16 x i32>``) and :class:`Mask` (16 booleans, ``<16 x i1>``), with the
arithmetic, comparisons and selects the compositing walks need, element by element in IEEE arithmetic (no fast-math
flags: the same operations in the same order as the scalar code give the same bits).

Why a type of our own: numba has no SIMD value type, and a block's state kept in 16-element stack arrays
(:mod:`.lanes`) made every Gaussian of a walk load and store each array (the loop over the lanes is a loop of its
own, with a masked remainder: ten loads and ten stores of 70 instructions, found in the assembly). A :class:`Vec`
is an LLVM SSA value: a walk's transmittance, sums and counts stay in vector registers from one Gaussian to the
next, and each scalar that meets a vector (a Gaussian's mean, conic, opacity) becomes a broadcast operand. LLVM
lowers ``<16 x float>`` to one AVX-512 register, two AVX ones or four of SSE or NEON: portable IR, nothing
CPU-specific. The scalar helpers of :mod:`.lanes` (``_gauss``, ``_blend``) run unchanged on vectors: the
operators below broadcast a scalar of the vector's dtype (any other dtype is a typing error, so float32 never
meets a float64 constant), and :func:`roodi_toolkit.render.lanes._fma`, ``_pick`` and ``min`` take vectors too.
"""

from __future__ import annotations

import operator

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, models, overload, register_model

LANES = 16
"""Pixels of a compositing block (4x4): the vector the compositing works on."""


class Vec(types.Type):
    """16 values of the numba scalar type ``dtype``: one per pixel of a 4x4 block."""

    def __init__(self, dtype):
        self.dtype = dtype
        super().__init__(name=f"Vec{LANES}[{dtype}]")


class Mask(types.Type):
    """16 booleans: one per pixel of a 4x4 block."""

    def __init__(self):
        super().__init__(name=f"Mask{LANES}")


MASK = Mask()


@register_model(Vec)
class _VecModel(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, ir.VectorType(dmm.lookup(fe_type.dtype).get_value_type(), LANES))


@register_model(Mask)
class _MaskModel(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, ir.VectorType(ir.IntType(1), LANES))


def _scalar(ty) -> bool:
    return isinstance(ty, (types.Float, types.Integer))


def halves(builder, vec):
    """The lanes 0-7 and 8-15 of the LLVM vector ``vec`` of 16 as two vectors of 8 (:mod:`.vectors` works on
    those)."""
    picks = ir.VectorType(ir.IntType(32), LANES // 2)
    return (builder.shuffle_vector(vec, vec, ir.Constant(picks, list(range(LANES // 2)))),
            builder.shuffle_vector(vec, vec, ir.Constant(picks, list(range(LANES // 2, LANES)))))


def _splat_ir(builder, value, vty):
    """An LLVM vector of type ``vty`` holding ``value`` in every lane."""
    vec = builder.insert_element(ir.Constant(vty, ir.Undefined), value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(vec, vec, ir.Constant(ir.VectorType(ir.IntType(32), LANES), [0] * LANES))


def _vec_of(*tys):
    """The one :class:`Vec` type among ``tys`` where every other is a scalar of its dtype, else None."""
    vecs = {t for t in tys if isinstance(t, Vec)}
    if len(vecs) != 1:
        return None
    (vt,) = vecs
    if all(t == vt or t == vt.dtype for t in tys):
        return vt
    return None


def _operands(context, builder, sig, args, vt):
    """``args`` as vectors of ``vt``: scalars broadcast."""
    vty = context.get_value_type(vt)
    return [a if isinstance(t, Vec) else _splat_ir(builder, a, vty) for t, a in zip(sig.args, args)]


@intrinsic
def splat(typingctx, x):  # pragma: no cover - compiled
    """A :class:`Vec` holding ``x`` in all 16 lanes."""
    if not _scalar(x):
        return None
    vt = Vec(x)

    def codegen(context, builder, signature, args):
        return _splat_ir(builder, args[0], context.get_value_type(vt))

    return vt(x), codegen


@intrinsic
def load(typingctx, arr, start):  # pragma: no cover - compiled
    """Elements ``start:start + 16`` of the C-contiguous 1-D array ``arr`` as a :class:`Vec` (no bounds check)."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C" and _scalar(arr.dtype)
            and isinstance(start, types.Integer)):
        return None
    vt = Vec(arr.dtype)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        ptr = builder.bitcast(builder.gep(data, [args[1]]), context.get_value_type(vt).as_pointer())
        return builder.load(ptr, align=arr.dtype.bitwidth // 8)

    return vt(arr, start), codegen


@intrinsic
def store(typingctx, arr, start, v):  # pragma: no cover - compiled
    """Write the :class:`Vec` ``v`` into elements ``start:start + 16`` of the C-contiguous 1-D array ``arr`` (no
    bounds check)."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C" and isinstance(v, Vec)
            and v.dtype == arr.dtype and isinstance(start, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        ptr = builder.bitcast(builder.gep(data, [args[1]]), args[2].type.as_pointer())
        builder.store(args[2], ptr, align=arr.dtype.bitwidth // 8)
        return context.get_dummy_value()

    return types.none(arr, start, v), codegen


def _arithmetic(float_op: str, int_op):
    @intrinsic
    def op(typingctx, a, b):  # pragma: no cover - compiled
        vt = _vec_of(a, b)
        if vt is None or (int_op is None and not isinstance(vt.dtype, types.Float)):
            return None

        def codegen(context, builder, signature, args):
            x, y = _operands(context, builder, signature, args, vt)
            return getattr(builder, float_op if isinstance(vt.dtype, types.Float) else int_op)(x, y)

        return vt(a, b), codegen

    return op


def _comparison(symbol: str):
    @intrinsic
    def op(typingctx, a, b):  # pragma: no cover - compiled
        vt = _vec_of(a, b)
        if vt is None:
            return None

        def codegen(context, builder, signature, args):
            x, y = _operands(context, builder, signature, args, vt)
            if isinstance(vt.dtype, types.Float):  # as Python's: False where either is NaN, but for !=
                return (builder.fcmp_unordered if symbol == "!=" else builder.fcmp_ordered)(symbol, x, y)
            return (builder.icmp_signed if vt.dtype.signed else builder.icmp_unsigned)(symbol, x, y)

        return MASK(a, b), codegen

    return op


def _logical(method: str):
    @intrinsic
    def op(typingctx, a, b):  # pragma: no cover - compiled
        if not (isinstance(a, Mask) and isinstance(b, Mask)):
            return None

        def codegen(context, builder, signature, args):
            return getattr(builder, method)(args[0], args[1])

        return MASK(a, b), codegen

    return op


@intrinsic
def _negate(typingctx, v):  # pragma: no cover - compiled
    """``-v`` lane by lane, as numba negates a float (``-0.0 - v``)."""
    if not (isinstance(v, Vec) and isinstance(v.dtype, types.Float)):
        return None

    def codegen(context, builder, signature, args):
        return builder.fsub(ir.Constant(args[0].type, [-0.0] * LANES), args[0])

    return v(v), codegen


@intrinsic
def _invert(typingctx, m):  # pragma: no cover - compiled
    if not isinstance(m, Mask):
        return None

    def codegen(context, builder, signature, args):
        return builder.not_(args[0])

    return MASK(m), codegen


def select_typed(m, a, b):
    """The typing of a lane-by-lane select (:func:`select`, :func:`roodi_toolkit.render.lanes._pick`): (the
    signature, the code) where ``m`` is a :class:`Mask` and ``a``, ``b`` a vector and a vector or a scalar of its
    dtype (broadcast), else None."""
    vt = _vec_of(a, b)
    if not isinstance(m, Mask) or vt is None:
        return None

    def codegen(context, builder, signature, args):
        x, y = _operands(context, builder, signature.replace(args=signature.args[1:]), args[1:], vt)
        return builder.select(args[0], x, y)

    return vt(m, a, b), codegen


def fma_typed(a, b, c):
    """The typing of a lane-by-lane ``a * b + c`` with one rounding where the CPU has fused multiply-add (LLVM's
    ``fmuladd``, as the scalar :func:`roodi_toolkit.render.lanes._fma`, which calls this for vectors: on such a CPU
    both are fused): (the signature, the code), or None where no operand is a float :class:`Vec`."""
    vt = _vec_of(a, b, c)
    if vt is None or not isinstance(vt.dtype, types.Float):
        return None

    def codegen(context, builder, signature, args):
        ops = _operands(context, builder, signature, args, vt)
        ty = ops[0].type
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ty, [ty, ty, ty]),
                                            f"llvm.fmuladd.v{LANES}f{vt.dtype.bitwidth}")
        return builder.call(fn, ops)

    return vt(a, b, c), codegen


@intrinsic
def select(typingctx, m, a, b):  # pragma: no cover - compiled
    """Lane by lane, ``a`` where the :class:`Mask` ``m`` is set, else ``b`` (LLVM's ``select``; a scalar of the
    vector's dtype is broadcast)."""
    return select_typed(m, a, b)


@intrinsic
def any_lane(typingctx, m):  # pragma: no cover - compiled
    """Whether any lane of the :class:`Mask` ``m`` is set (a mask test: one or two instructions)."""
    if not isinstance(m, Mask):
        return None

    def codegen(context, builder, signature, args):
        bits = builder.bitcast(args[0], ir.IntType(LANES))
        return builder.icmp_unsigned("!=", bits, ir.Constant(ir.IntType(LANES), 0))

    return types.boolean(m), codegen


def _vector_operator(impl):
    def typed(a, b):
        if _vec_of(a, b) is not None:
            return lambda a, b: impl(a, b)
        return None

    return typed


def _mask_operator(impl):
    def typed(a, b):
        if isinstance(a, Mask) and isinstance(b, Mask):
            return lambda a, b: impl(a, b)
        return None

    return typed


def _register_operators():
    """Python's operators and ``min`` on :class:`Vec` and :class:`Mask` values."""
    add, sub, mul = _arithmetic("fadd", "add"), _arithmetic("fsub", "sub"), _arithmetic("fmul", "mul")
    div = _arithmetic("fdiv", None)
    for python_op, impl in ((operator.add, add), (operator.iadd, add), (operator.sub, sub), (operator.isub, sub),
                            (operator.mul, mul), (operator.imul, mul), (operator.truediv, div),
                            (operator.itruediv, div), (operator.lt, _comparison("<")),
                            (operator.le, _comparison("<=")), (operator.gt, _comparison(">")),
                            (operator.ge, _comparison(">=")), (operator.eq, _comparison("==")),
                            (operator.ne, _comparison("!="))):
        overload(python_op)(_vector_operator(impl))
    for python_op, impl in ((operator.and_, _logical("and_")), (operator.or_, _logical("or_"))):
        overload(python_op)(_mask_operator(impl))

    @overload(operator.neg)
    def _negated(v):
        if isinstance(v, Vec):
            return lambda v: _negate(v)
        return None

    @overload(operator.invert)
    def _inverted(m):
        if isinstance(m, Mask):
            return lambda m: _invert(m)
        return None

    @overload(min)
    def _smaller(a, b):
        """Numba's ``min(a, b)`` of two numbers, lane by lane: ``b if b < a else a`` (``a`` where either is NaN)."""
        if _vec_of(a, b) is not None:
            return lambda a, b: select(b < a, b, a)
        return None


_register_operators()
