"""Shared test fixtures.

``rng``: every test that draws random inputs owns its generator, seeded from the
test's own id, so its inputs never depend on which tests ran before it (the suite
runs in random order) and a failure is reproduced by running the test alone.
"""

import zlib

import numpy as np
import pytest


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A generator seeded by the test's node id (stable across runs and orders)."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))
