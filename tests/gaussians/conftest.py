"""Fixtures of the rasterizer tests (helpers: :mod:`tests.helpers`)."""

from __future__ import annotations

import pytest

# Tests import helpers from tests.helpers; these names stay importable from here only for tests
# written before the move (``from .conftest import assert_close``): import them from tests.helpers.
from tests.helpers import FAST_BACKENDS, GRAD_FIELDS, OUTPUTS, assert_close, outputs_and_grads, render  # noqa: F401


@pytest.fixture(params=FAST_BACKENDS)
def fast_backend(request):
    return request.param
