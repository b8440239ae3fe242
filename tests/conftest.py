"""Shared fixtures for the jaxnav test suite.

Nothing here touches global JAX configuration: the suite runs in JAX's
default float32. A test that needs float64 enables it locally with the
``jax.enable_x64(True)`` context manager.
"""

from __future__ import annotations

import itertools
import zlib

import jax
import pytest


@pytest.fixture
def getkey(request):
    """A factory of fresh PRNG keys: every call returns a new, independent key.

    The keys are reproducible: the stream is seeded from the test's node id
    (stable across runs and independent of test order), and the ``i``-th call
    returns ``fold_in(base, i)``. Raw ``uint32[2]`` keys (``PRNGKey``) are used
    so the keys work with every jax.random API and with NumPy conversion.
    """
    base = jax.random.PRNGKey(zlib.crc32(request.node.nodeid.encode()))
    counter = itertools.count()

    def _getkey() -> jax.Array:
        return jax.random.fold_in(base, next(counter))

    return _getkey
