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
and child processes whose programs run long (the documentation examples and the
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
    # Every program, however quick to compile: the in-memory caches are dropped after each file, and
    # small programs recur across files (tests/localization, models and sim on two cores: 184–192 s
    # with every program cached against 199–201 s with those over 0.3 s only; compilation 12 % less).
    os.environ.setdefault(_MIN_COMPILE_ENV, "0")
    # jax was imported above, before the variables were set: configure it directly too.
    jax.config.update("jax_compilation_cache_dir", os.environ[_CACHE_ENV])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(os.environ[_MIN_COMPILE_ENV]))
    if config.getoption("--compile-report"):
        from jax import monitoring

        monitoring.register_event_duration_secs_listener(_on_duration_event)
        monitoring.register_event_listener(_on_event)


# The slowest test files, slowest first (worker-seconds on two cores): collected first, so that xdist
# (``--dist loadfile --no-loadscope-reorder``: whole files, in collection order) starts them first; a
# slow file started last would leave the other worker idle at the end.
SLOW_FILES = (
    "tests/slam/test_fastslam.py",
    "tests/experiments/test_experiments_quick.py",
    "tests/test_notebooks.py",
    "tests/slam/test_pf_slam.py",
    "tests/test_docs.py",
    "tests/test_docs_guides.py",
    "tests/test_cli.py",
    "tests/experiments/test_ir_experiments.py",
    "tests/slam/test_hf_slam_runs.py",
    "tests/test_calibration.py",
    "tests/core/test_gradient_estimators.py",
    "tests/core/test_processes.py",
    "tests/core/test_devices.py",
    "tests/localization/test_mcl_sharded.py",
    "tests/core/test_resampling_exact.py",
    "tests/localization/test_rfid_anchor.py",
    "tests/localization/test_localization_agreement.py",
    "tests/slam/test_scan_body_hlo.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {path: i for i, path in enumerate(SLOW_FILES)}
    items.sort(key=lambda item: rank.get(item.nodeid.partition("::")[0], len(SLOW_FILES)))  # stable: files stay whole


def pytest_collection_finish(session):
    """Move what the imports and the collection made (modules, functions, JAX's tables) out of the
    garbage collector's reach: a full collection, after each file and whenever Python starts one,
    then scans only what the tests made (tests/localization on two workers: 28.7 → 17.6 s of
    collection)."""
    gc.collect()
    gc.freeze()


# --------------------------------------------------------------------------- where the compile time goes

# jax.monitoring's duration events of the three stages between a Python function and a program.
_COMPILE_STAGES = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}
# Of the compile stage: programs loaded from the persistent cache, programs compiled, seconds loading.
_CACHE_EVENTS = {"/jax/compilation_cache/cache_hits": "loaded"}
_CACHE_LOAD_EVENT = "/jax/compilation_cache/cache_retrieval_time_sec"
_COMPILE_PROPERTY = "jax_compile_seconds"
_stage_seconds: dict[str, float] = {}  # this test's seconds per stage, so far
_compile_report: dict[str, dict[str, float]] = {}  # on the controller: test file -> stage -> seconds


def pytest_addoption(parser):
    parser.addoption(
        "--compile-report",
        action="store_true",
        help="after the run, list the test files by the seconds JAX spent tracing, lowering and compiling "
        "their programs (in the test processes; notebooks and CLI subprocesses are not counted)",
    )


def _on_duration_event(event: str, duration: float, **_: object) -> None:
    stage = _COMPILE_STAGES.get(event) or ("load" if event == _CACHE_LOAD_EVENT else None)
    if stage is not None:
        _stage_seconds[stage] = _stage_seconds.get(stage, 0.0) + duration
    if stage == "compile":  # every program that reached the backend, loaded from the cache or compiled
        _stage_seconds["programs"] = _stage_seconds.get("programs", 0.0) + 1


def _on_event(event: str, **_: object) -> None:
    count = _CACHE_EVENTS.get(event)
    if count is not None:
        _stage_seconds[count] = _stage_seconds.get(count, 0.0) + 1


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """With ``--compile-report``: a test's stage seconds (its setup, call and teardown, the module
    fixtures it starts or ends included) travel with its teardown report, across xdist workers too."""
    if item.config.getoption("--compile-report") and call.when == "teardown":
        item.user_properties.append((_COMPILE_PROPERTY, dict(_stage_seconds)))
        _stage_seconds.clear()
    yield


def pytest_runtest_logreport(report):
    if report.when != "teardown":
        return
    for name, seconds in report.user_properties:
        if name == _COMPILE_PROPERTY:
            per_file = _compile_report.setdefault(report.nodeid.partition("::")[0], {})
            for stage, s in seconds.items():
                per_file[stage] = per_file.get(stage, 0.0) + s


def pytest_terminal_summary(terminalreporter, config):
    if not config.getoption("--compile-report") or not _compile_report:
        return
    for seconds in _compile_report.values():
        seconds["compiled"] = seconds.get("programs", 0.0) - seconds.get("loaded", 0.0)
    stages = [*_COMPILE_STAGES.values(), "load", "loaded", "compiled"]
    rows = sorted(_compile_report.items(), key=lambda kv: -sum(kv[1].get(st, 0.0) for st in _COMPILE_STAGES.values()))
    totals = {st: sum(r.get(st, 0.0) for _, r in rows) for st in stages}
    terminalreporter.write_sep(
        "=", "JAX compile time by test file (seconds; 'load': of compile, from the persistent cache; programs)"
    )
    terminalreporter.write_line(" ".join(f"{st:>8}" for st in stages) + "  file")
    terminalreporter.write_line(" ".join(f"{totals[st]:8.1f}" for st in stages) + "  (all files)")
    for path, seconds in rows[:25]:
        terminalreporter.write_line(" ".join(f"{seconds.get(st, 0.0):8.1f}" for st in stages) + f"  {path}")


def pytest_unconfigure(config):
    if _made_cache_dir is not None:
        shutil.rmtree(_made_cache_dir, ignore_errors=True)


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Drop JAX's in-memory compiled programs after each test file. A worker that keeps every program
    it compiled grows to several GB over the suite; programs shared between files are mostly small,
    and come back from the persistent cache."""
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
