"""Slab test of a wide node's eight child boxes at once, in LLVM vector instructions.

The slab test is Kay & Kajiya's ("Ray Tracing Complex Scenes", SIGGRAPH
1986), with the near face of each axis chosen once per ray (pbrt's
``dirIsNeg``) and NaN-safe bounds (:func:`.traverse.tighten`): a NaN from
``0 * inf`` (an origin on a slab plane, a zero direction component) never
replaces the running entry or exit distance.

A wide record stores each box component for its eight children side by side
(:mod:`.wide`), so one 32-byte load fetches, say, ``lo_x`` of all eight. Written
as scalar code, Numba leaves the children's tests scalar: LLVM's SLP
vectoriser, which would merge them, is off in Numba by default
(``NUMBA_SLP_VECTORIZE=0``), and a library must not switch it on for its
users' code. :func:`enter_children` therefore emits the vector IR itself: per
axis, two loads of eight float32 components, widened to eight float64 lanes,
then subtract, multiply and select on all eight children at once (on AVX2, as
``inspect_asm()`` shows: ``vcvtps2pd``, ``vsubpd``, ``vmulpd``, ``vmaxpd`` and
``vminpd`` on pairs of ``ymm`` registers; on AVX-512 one ``zmm`` register
each, since Numba sets no ``min-legal-vector-width`` and LLVM then takes
512-bit vectors as legal; forcing pairs of ``ymm`` there made no walk
faster: incoherent rays x0.98 to x1.01, camera rays x0.87). The arithmetic
is exactly the scalar test's, lane by lane, in float64, so it culls exactly
the same nodes.
It returns the entered children as the bits of an integer, which the
traversal walks with :func:`highest_bit`, as Embree's does with its
``movemask``; computing the same test in float32 lanes instead was not faster
(four-wide nodes, full dragon, one thread: x0.98 to x1.03).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from .wide import WIDTH

__all__ = ["enter_children", "highest_bit", "lowest_bit", "splat", "tighten_lanes", "tighten_to_slab",
           "entered_children"]


@intrinsic
def enter_children(typingctx, records, node, near_x, near_y, near_z, origin, inv_dir, t_min, t_max, entry):
    """Test the ray against the child boxes of wide ``node``: writes into ``entry[c]`` the
    distance at which it enters child ``c`` within ``[t_min, t_max]``, ``inf`` where it misses,
    and returns the mask of the children it enters (bit ``c`` for child ``c``). ``records`` is
    the (n, 64) float32 wide layout, ``near_*`` the column block (0-5) of each axis's near face,
    ``origin`` and ``inv_dir`` float64 triples, ``entry`` a contiguous float64 array of
    ``WIDTH`` or more."""
    signature = types.int64(records, node, near_x, near_y, near_z, origin, inv_dir, t_min, t_max, entry)

    def codegen(context, builder, sig, args):
        records_type = sig.args[0]
        array, node_index, *nears, origin_value, inv_value, enter_limit, exit_limit, entry_array = args
        view = context.make_array(records_type)(context, builder, array)
        row = cgutils.get_item_pointer(context, builder, records_type, view,
                                       [context.cast(builder, node_index, sig.args[1], types.intp),
                                        context.get_constant(types.intp, 0)])
        floats = ir.VectorType(ir.FloatType(), WIDTH)
        doubles = ir.VectorType(ir.DoubleType(), WIDTH)
        intp = context.get_value_type(types.intp)

        def component(block):
            pointer = builder.gep(row, [builder.mul(block, ir.Constant(intp, WIDTH))])
            return builder.fpext(builder.load(builder.bitcast(pointer, floats.as_pointer()), align=32), doubles)

        enter = splat(builder, enter_limit, doubles)
        exit_ = splat(builder, exit_limit, doubles)
        for axis in range(3):
            o = splat(builder, builder.extract_value(origin_value, axis), doubles)
            inv = splat(builder, builder.extract_value(inv_value, axis), doubles)
            near_block = context.cast(builder, nears[axis], sig.args[2 + axis], types.intp)
            far_block = builder.sub(ir.Constant(intp, 2 * axis + 3), near_block)
            enter, exit_ = tighten_to_slab(builder, component(near_block), component(far_block), o, inv, enter, exit_)
        return entered_children(context, builder, sig.args[9], entry_array, enter, exit_)

    return signature, codegen


def splat(builder, value, vector_type):
    """The IR of a vector of ``vector_type`` with ``value`` in every lane."""
    vector = ir.Constant(vector_type, ir.Undefined)
    for lane in range(vector_type.count):
        vector = builder.insert_element(vector, value, ir.IntType(32)(lane))
    return vector


def tighten_lanes(builder, near, far, enter, exit_):
    """The IR of :func:`.traverse.tighten` on vectors: each lane's interval narrowed to a slab's
    ``[near, far]``, a NaN bound (``0 * inf``) leaving it as it was."""
    enter = builder.select(builder.fcmp_ordered(">", near, enter), near, enter)
    exit_ = builder.select(builder.fcmp_ordered("<", far, exit_), far, exit_)
    return enter, exit_


def tighten_to_slab(builder, near_face, far_face, origin, inverse, enter, exit_):
    """The IR of one slab of the slab test on vectors: the distances ``(face - origin) * inverse``
    to the near and far faces, each lane's interval narrowed to them (:func:`tighten_lanes`)."""
    near = builder.fmul(builder.fsub(near_face, origin), inverse)
    far = builder.fmul(builder.fsub(far_face, origin), inverse)
    return tighten_lanes(builder, near, far, enter, exit_)


def entered_children(context, builder, entry_type, entry_array, enter, exit_):
    """The IR that ends a test of eight child boxes: stores each child's entry distance (``inf``
    where the interval is empty) into the ``entry`` array and returns the mask of the entered."""
    doubles = enter.type
    entered = builder.fcmp_ordered("<=", enter, exit_)
    missed = ir.Constant(doubles, [float("inf")] * WIDTH)
    entry_view = context.make_array(entry_type)(context, builder, entry_array)
    builder.store(builder.select(entered, enter, missed), builder.bitcast(entry_view.data, doubles.as_pointer()),
                  align=8)
    return builder.zext(builder.bitcast(entered, ir.IntType(WIDTH)), ir.IntType(64))


def _zero_bits(builder, name, mask):
    """The IR counting ``mask``'s zero bits from one end: LLVM's ``name``, ``ctlz`` (leading) or
    ``cttz`` (trailing), on an int64 other than 0."""
    int64 = ir.IntType(64)
    count = cgutils.get_or_insert_function(builder.module, ir.FunctionType(int64, [int64, ir.IntType(1)]),
                                           f"llvm.{name}.i64")
    return builder.call(count, [mask, ir.IntType(1)(1)])


@intrinsic
def highest_bit(typingctx, mask):
    """The index of the highest set bit of ``mask`` (an int64 other than 0): one ``lzcnt``."""
    signature = types.int64(mask)

    def codegen(context, builder, sig, args):
        mask_value = context.cast(builder, args[0], sig.args[0], types.int64)
        return builder.sub(ir.IntType(64)(63), _zero_bits(builder, "ctlz", mask_value))

    return signature, codegen


@intrinsic
def lowest_bit(typingctx, mask):
    """The index of the lowest set bit of ``mask`` (an int64 other than 0): one ``tzcnt``."""
    signature = types.int64(mask)

    def codegen(context, builder, sig, args):
        return _zero_bits(builder, "cttz", context.cast(builder, args[0], sig.args[0], types.int64))

    return signature, codegen
