"""rayaccel's kernels compile with the scopes of inlined functions shared by their IR copies
(``rayaccel._jit._scopes_shared_by_copies``), and nothing else compiled in the process does."""

from __future__ import annotations

import copy

import numba
import numpy as np
from numba.core import ir

import rayaccel as ra
from rayaccel._jit import _scopes_shared_by_copies


def test_scopes_are_shared_only_inside_the_context():
    scope = ir.Scope(None, ir.Loc("test", 1))
    assert copy.deepcopy(scope) is not scope
    with _scopes_shared_by_copies():
        assert copy.deepcopy(scope) is scope
    assert copy.deepcopy(scope) is not scope
    assert "__deepcopy__" not in vars(ir.Scope)


def test_a_users_inlined_function_compiles_as_before_after_rayaccel_compiled(bunny):
    ra.build(bunny, "bvh-binned").intersect(np.zeros((4, 3)), np.ones((4, 3)))
    assert "__deepcopy__" not in vars(ir.Scope)

    @numba.njit(inline="always")
    def shifted(x, shift):
        if shift > 0:
            return x + shift
        return x - shift

    @numba.njit
    def both(x):
        return shifted(x, 1) * shifted(x, -2)

    assert both(3) == 20
