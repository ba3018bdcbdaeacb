"""Fixtures of the rasterizer tests (helpers: :mod:`tests.helpers`, imported from there)."""

from __future__ import annotations

import pytest

from tests.helpers import FAST_BACKENDS


@pytest.fixture(params=FAST_BACKENDS)
def fast_backend(request):
    return request.param
