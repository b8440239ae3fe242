"""Shared fixtures for the jaxnav test suite.

The suite runs in JAX's default float32. A test that needs float64 enables it
locally with the ``jax.enable_x64(True)`` context manager.

Compilation is most of the suite's time (its programs are small and run
briefly), so two pieces of global configuration make it cheaper. Both apply
to this process and to everything it starts (xdist workers, notebook
kernels, CLI subprocesses); neither changes what a program means (results
may differ in the last bits of a float, as between two XLA versions).

* **XLA flags** :data:`TEST_XLA_FLAGS` are appended to ``XLA_FLAGS``: the
  CPU backend's LLVM optimisation off and the older fusion code generator,
  which compile several times faster and run several times slower; for the
  suite's small programs the compilation saved outweighs the run time lost
  (compile-heavy files such as test_fastslam, test_mcl and test_pf_slam take
  well under half as long). Set ``JAXNAV_TEST_XLA_DEFAULTS=1`` to test with XLA's defaults.
* **One persistent compilation cache** per session (a temporary directory,
  removed at the end), so a program compiled in one process (a quick
  experiment's cell, say, that a notebook runs again) is not compiled again
  in another. Set ``JAX_COMPILATION_CACHE_DIR`` to choose the directory (it
  is then kept).

Two more keep a worker small and the slow parts short: JAX's in-memory programs
are dropped after each test file (a worker that kept them all grew past 6 GB),
and child processes whose programs run long (the documentation's examples, the
notebooks that run more than they compile) get XLA's default flags (:func:`xla_defaults_env`).
"""

from __future__ import annotations

import gc
import itertools
import os
import shutil
import tempfile
import zlib

TEST_XLA_FLAGS = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")
# The user's own XLA_FLAGS, before the suite adds its own; set once, by the first process (xdist
# workers and other children inherit it with the flags already added).
_USER_FLAGS_ENV = "JAXNAV_TEST_USER_XLA_FLAGS"
os.environ.setdefault(_USER_FLAGS_ENV, os.environ.get("XLA_FLAGS", ""))
if os.environ.get("JAXNAV_TEST_XLA_DEFAULTS") != "1":
    # Before jax starts its backend (importing jax does not): XLA reads the flags once.
    _flags = os.environ.get("XLA_FLAGS", "").split()
    os.environ["XLA_FLAGS"] = " ".join(_flags + [f for f in TEST_XLA_FLAGS if f not in _flags])

import jax  # noqa: E402
import pytest  # noqa: E402

_CACHE_ENV = "JAX_COMPILATION_CACHE_DIR"
_MIN_COMPILE_ENV = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"
_made_cache_dir: str | None = None


def pytest_configure(config):
    """Point this process and its children (xdist workers, notebook kernels) at one compilation cache."""
    global _made_cache_dir
    if not os.environ.get(_CACHE_ENV):  # the controller (or a run without xdist): make the directory
        _made_cache_dir = tempfile.mkdtemp(prefix="jaxnav-test-xla-cache-")
        os.environ[_CACHE_ENV] = _made_cache_dir
    # Programs that compile in under 0.3 s are not worth a disk round trip.
    os.environ.setdefault(_MIN_COMPILE_ENV, "0.3")
    # jax was imported above, before the variables were set: configure it directly too.
    jax.config.update("jax_compilation_cache_dir", os.environ[_CACHE_ENV])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(os.environ[_MIN_COMPILE_ENV]))


# The slowest test files, slowest first (worker-seconds on two cores): collected first, so that xdist
# (``--dist loadfile --no-loadscope-reorder``: whole files, in collection order) starts them first; a
# slow file started last would leave the other worker idle at the end.
SLOW_FILES = (
    "tests/slam/test_fastslam.py",
    "tests/experiments/test_experiments_quick.py",
    "tests/test_notebooks.py",
    "tests/slam/test_pf_slam.py",
    "tests/test_cli.py",
    "tests/experiments/test_ir_experiments.py",
    "tests/slam/test_hf_slam_runs.py",
    "tests/core/test_resampling_exact.py",
    "tests/localization/test_rfid_anchor.py",
    "tests/localization/test_localization_agreement.py",
    "tests/slam/test_scan_body_hlo.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {path: i for i, path in enumerate(SLOW_FILES)}
    items.sort(key=lambda item: rank.get(item.nodeid.partition("::")[0], len(SLOW_FILES)))  # stable: files stay whole


def pytest_unconfigure(config):
    if _made_cache_dir is not None:
        shutil.rmtree(_made_cache_dir, ignore_errors=True)


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Drop JAX's in-memory compiled programs after each test file. A worker that keeps every program
    it compiled grows to several GB over the suite; programs shared between files are mostly small,
    and those worth keeping (over 0.3 s to compile) come back from the persistent cache."""
    yield
    jax.clear_caches()
    gc.collect()


@pytest.fixture(scope="session")
def xla_defaults_env() -> dict[str, str]:
    """This process's environment with :data:`TEST_XLA_FLAGS` taken out of ``XLA_FLAGS``: for a child
    process (a notebook kernel, a script) whose programs run long enough that XLA's optimisations
    save more time than they cost to compile."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = os.environ[_USER_FLAGS_ENV]
    return env


def seed_id(nodeid: str) -> str:
    """``tests/<dir>/test_x.py::name`` → ``tests/test_x.py::name``: the id the keys are seeded from."""
    path, sep, rest = nodeid.partition("::")
    return "tests/" + os.path.basename(path) + sep + rest


@pytest.fixture
def test_seed(request) -> int:
    """A per-test seed: the CRC-32 of :func:`seed_id` of the test's node id."""
    return zlib.crc32(seed_id(request.node.nodeid).encode())


@pytest.fixture
def getkey(request):
    """A factory of fresh PRNG keys: every call returns a new, independent key.

    The keys are reproducible: the stream is seeded from the test's node id
    (stable across runs and independent of test order) with the test file's
    directory left out (:func:`seed_id`), so moving a test file between the
    directories of ``tests/`` keeps its keys; the ``i``-th call returns
    ``fold_in(base, i)``. Raw ``uint32[2]`` keys (``PRNGKey``) are used so the
    keys work with every jax.random API and with NumPy conversion.
    """
    base = jax.random.PRNGKey(zlib.crc32(seed_id(request.node.nodeid).encode()))
    counter = itertools.count()

    def _getkey() -> jax.Array:
        return jax.random.fold_in(base, next(counter))

    return _getkey
