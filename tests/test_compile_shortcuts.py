"""rayaccel's kernels compile under four shortcuts through Numba (``rayaccel._jit._compile_shortcuts``):
the scopes of inlined functions shared by their IR copies, rayaccel's always-inlined overloads typed once
per argument types, copy propagation's sets of names copied flat and liveness found on bit sets. Each gives
what Numba gives without it, and nothing else compiled in the process sees them. Chunk kernels compile
through the parallel pipeline less its search for parallel loops (``rayaccel._jit._NoParforSearch``), to
the same code."""

from __future__ import annotations

import collections
import copy
import re

import numba
import numpy as np
import pytest
from numba.core import analysis, compiler, ir, ir_utils, types
from numba.core.registry import cpu_target
from numba.core.typing import templates
from numba.extending import overload
from numba.parfors import parfor

import rayaccel as ra
from rayaccel import _jit
from rayaccel._jit import (
    _FlatCopiesOfNameSets,
    _inline_overloads_typed_once,
    _live_map_by_bits,
    _live_maps_by_bits,
    _name_sets_copied_flat,
    _scopes_shared_by_copies,
)
from rayaccel._validate import _unusable_rays, unusable_rays


def test_scopes_are_shared_only_inside_the_context():
    scope = ir.Scope(None, ir.Loc("test", 1))
    assert copy.deepcopy(scope) is not scope
    with _scopes_shared_by_copies():
        assert copy.deepcopy(scope) is scope
    assert copy.deepcopy(scope) is not scope
    assert "__deepcopy__" not in vars(ir.Scope)


def test_a_users_inlined_function_compiles_as_before_after_rayaccel_compiled(bunny):
    generic = vars(templates._OverloadFunctionTemplate)["generic"]
    ra.build(bunny, "bvh-binned").intersect(np.zeros((4, 3)), np.ones((4, 3)))
    assert "__deepcopy__" not in vars(ir.Scope)
    assert vars(templates._OverloadFunctionTemplate)["generic"] is generic
    assert ir_utils.copy is copy

    @numba.njit(inline="always")
    def shifted(x, shift):
        if shift > 0:
            return x + shift
        return x - shift

    @numba.njit
    def both(x):
        return shifted(x, 1) * shifted(x, -2)

    assert both(3) == 20


def _users_half(x):
    """A user's overload inlined at every call, in this test module."""


@overload(_users_half, inline="always")
def _users_half_overload(x):
    return lambda x: x / 2


@pytest.fixture
def typings(monkeypatch):
    """The overloads whose calls Numba's own typing typed, in turn; rayaccel's memory of the
    signatures it gave starts empty."""
    calls = []
    generic = templates._OverloadFunctionTemplate.generic

    def counted(self, args, kws):
        calls.append(self._overload_func)
        return generic(self, args, kws)

    monkeypatch.setattr(templates._OverloadFunctionTemplate, "generic", counted)
    monkeypatch.setattr(_jit, "_INLINE_SIGNATURES", {})
    return calls


def _typed_twice(function, args):
    context = cpu_target.typing_context
    template, = context.resolve_value_type(function).templates
    return template(context).generic(args, {}), template(context).generic(args, {})


def test_rayaccels_inline_overloads_are_typed_once_per_argument_types_only_inside_the_context(typings):
    rays = types.Array(types.float32, 2, "A")
    args = (rays, rays, types.int64, types.int64)
    with _inline_overloads_typed_once():
        first, second = _typed_twice(unusable_rays, args)
        assert first == second and first.return_type == types.int64
        assert typings.count(_unusable_rays) == 1
        _typed_twice(unusable_rays, (rays, types.Array(types.float64, 2, "A"), types.int64, types.int64))
        assert typings.count(_unusable_rays) == 2
    _typed_twice(unusable_rays, args)
    assert typings.count(_unusable_rays) == 4


def test_a_users_inline_overload_is_typed_as_numba_types_it_inside_the_context(typings):
    with _inline_overloads_typed_once():
        first, second = _typed_twice(_users_half, (types.float64,))
    assert first == second and first.return_type == types.float64
    assert typings.count(_users_half_overload) == 2


def _branching(values, limit):
    total = 0.0
    alias = values
    for value in alias:
        step = value
        if step > limit:
            other = step
            total += other
        else:
            kept = limit
            total -= kept
    result = total
    return result


def test_copy_propagation_finds_the_same_copies_with_its_name_sets_copied_flat():
    blocks = compiler.run_frontend(_branching).blocks
    one_type = collections.defaultdict(lambda: types.float64)
    expected = ir_utils.copy_propagate(blocks, one_type)
    with _name_sets_copied_flat():
        assert ir_utils.copy is _FlatCopiesOfNameSets
        found = ir_utils.copy_propagate(blocks, one_type)
    assert ir_utils.copy is copy
    assert found == expected
    assert any(expected[1].values()), "the function should have copies to propagate"


def test_flat_copies_are_copies_of_name_sets_and_deep_copies_of_anything_else():
    name_sets = {0: {("a", "b"), ("c", "d")}, 4: {"e"}, 8: set()}
    copied = _FlatCopiesOfNameSets.deepcopy(name_sets)
    assert copied == name_sets
    copied[0].add(("x", "y"))
    assert ("x", "y") not in name_sets[0]
    nested = {0: {("a", "b")}, 1: [["list"]]}
    deep = _FlatCopiesOfNameSets.deepcopy(nested)
    assert deep == nested and deep[1][0] is not nested[1][0]
    holding_a_var = {0: {ir.Var(ir.Scope(None, ir.Loc("test", 1)), "v", ir.Loc("test", 1))}}
    assert next(iter(_FlatCopiesOfNameSets.deepcopy(holding_a_var)[0])) is not next(iter(holding_a_var[0]))


def _nested_loops(values, limit):
    found = -1
    for i in range(values.shape[0]):
        total = 0.0
        for j in range(i, values.shape[0]):
            step = values[j]
            if step > limit:
                break
            total += step
        if total > limit:
            found = i
            continue
        while total > 0.0:
            total -= 1.0
    return found


@pytest.mark.parametrize("function", [_branching, _nested_loops], ids=["branches", "nested loops"])
def test_liveness_on_bit_sets_finds_numbas_sets(function):
    blocks = compiler.run_frontend(function).blocks
    cfg = analysis.compute_cfg_from_blocks(blocks)
    use_defs = analysis.compute_use_defs(blocks)
    expected = analysis.compute_live_map(cfg, blocks, use_defs.usemap, use_defs.defmap)
    assert _live_map_by_bits(cfg, blocks, use_defs.usemap, use_defs.defmap) == expected
    assert any(expected.values()) and len(expected) > 3


def test_liveness_on_bit_sets_only_inside_the_context():
    original = analysis.compute_live_map
    with _live_maps_by_bits():
        assert analysis.compute_live_map is ir_utils.compute_live_map is parfor.compute_live_map is _live_map_by_bits
    assert analysis.compute_live_map is ir_utils.compute_live_map is parfor.compute_live_map is original


@numba.njit(inline="always")
def _weighted(values, weights, k):
    if weights[k] > 0.0:
        return values[k] * weights[k], 1
    return 0.0, 0


@numba.njit(inline="always")
def _visit_run(values, weights, out, first, n, total, count):
    for k in range(first, first + n):
        add, hit = _weighted(values, weights, k)
        total, count = total + add, count + hit
        out[k] = total
        if total > 100.0:
            break
    return total, count


def _walk_like(first, end, values, weights, out):
    """A chunk kernel's shape: a serial loop over its items through functions inlined at the IR level
    that take its arrays, some items visiting a run of others as a walk visits a leaf."""
    total = 0.0
    count = 0
    item = first
    while item < end:
        if weights[item] < 0.5:
            total, count = _visit_run(values, weights, out, item, 3, total, count)
            item += 3
        else:
            item += 1
    return total, count


def _machine_code(dispatcher, signature):
    """The assembly of ``dispatcher`` for ``signature``, its symbol, label and constant names set aside."""
    code = dispatcher.inspect_asm(signature)
    for pattern in (r"_ZN[\w$.]+", r"\.L\w+", r'"?\.(const|bytes)\.[\w.-]+"?'):
        code = re.sub(pattern, "NAME", code)
    return [line for line in code.splitlines() if not re.match(r"\s*\.(file|ident|section|size|ascii|asciz)", line)]


@pytest.mark.filterwarnings("ignore:(?s).*'parallel=True' was specified:numba.core.errors.NumbaPerformanceWarning")
def test_chunk_kernels_skip_the_search_for_parallel_loops_and_compile_to_the_same_code():
    """The parallel pipeline without ``ParforPass`` and ``ParforFusionPass`` compiles the same machine
    code as with them, for a function whose code the parallel pipeline changes (the serial
    pipeline's differs)."""
    signature = (types.int64, types.int64, types.float64[::1], types.float64[::1], types.float64[::1])
    serial = numba.njit(**_jit._COMMON)(_walk_like)
    through_numba = numba.njit(parallel=True, **_jit._COMMON)(_walk_like)
    through_rayaccel = numba.njit(parallel=True, pipeline_class=_jit._NoParforSearch, **_jit._COMMON)(_walk_like)
    for dispatcher in (serial, through_numba, through_rayaccel):
        dispatcher.compile(signature)
    passes_run = [set(name.split("_", 1)[1] for times in dispatcher.overloads[signature].metadata["pipeline_times"]
                      .values() for name in times) for dispatcher in (through_numba, through_rayaccel)]
    assert {"parfor_pass", "parfor_fusion_pass", "parfor_prelowering_pass"} <= passes_run[0]
    assert "parfor_pass" not in passes_run[1] and "parfor_fusion_pass" not in passes_run[1]
    assert "parfor_prelowering_pass" in passes_run[1]
    assert _machine_code(serial, signature) != _machine_code(through_numba, signature)
    assert _machine_code(through_rayaccel, signature) == _machine_code(through_numba, signature)
    values, weights, out = np.arange(8.0), np.array([0.1, 1.0, 1.0, 1.0, 0.2, 0.0, 1.0, 1.0]), np.zeros(8)
    total, count = through_rayaccel(0, 8, values, weights, out)
    assert (total, count) == (pytest.approx(3.0 + 4.0 * 0.2 + 6.0), 5)
    np.testing.assert_allclose(out, [0.0, 1.0, 3.0, 0.0, 3.8, 3.8, 9.8, 0.0])
