import gc
import os
import shutil
import tempfile

import pytest

import axialmix  # noqa: F401  (float64 for every test)

# The suite's processes (the two workers and the command-line runs they start) keep their
# compiled programs in one cache folder of their own, made by the process that starts the
# workers and removed by it at the end: the suite neither reads nor fills the user's cache,
# and a program one process compiled is loaded by the others, as users' processes share
# theirs (the cache is on by default; the locking of a shared folder is tested on its own,
# in tests/test_compilation_cache.py). In two full runs on the same 2 cores, the tests took
# 1,775 s summed against 1,987 s without the cache (922 s against 1,038 s of wall
# time). AXIALMIX_COMPILATION_CACHE=off in the environment runs the suite without a cache.
_SHARED = "AXIALMIX_TEST_CACHE"
_OWNER = os.environ.get(_SHARED) is None
if _OWNER:
    _CACHE = tempfile.mkdtemp(prefix="axialmix-tests-")
    os.environ[_SHARED] = _CACHE  # inherited by the workers, which start later
else:
    _CACHE = os.environ[_SHARED]
os.environ["XDG_CACHE_HOME"] = _CACHE
os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
os.environ.setdefault("AXIALMIX_COMPILATION_CACHE", "on")


# Every compiled program keeps a few memory mappings of its machine code (about six), and a
# process may hold at most vm.max_map_count of them (65,530 by default). A test process that
# compiles thousands of programs reaches it, and then XLA's next allocation for code fails
# inside the compiler: the segmentation faults this suite used to see in its workers (a
# worker had 27,000 mappings near the end of a run). Past a share of the limit, the compiled
# programs are let go after a test module (they are compiled again where needed).
_MAPPING_SHARE = 0.4


def _mappings() -> tuple[int, int]:
    """This process's memory mappings and the most it may hold (0, 0 where unknown)."""
    try:
        with open("/proc/self/maps") as stream:
            held = sum(1 for _ in stream)
        with open("/proc/sys/vm/max_map_count") as stream:
            return held, int(stream.read())
    except (OSError, ValueError):
        return 0, 0


def release_compiled_programs() -> None:
    """Drop every compiled program of this process: JAX's caches and the project's own."""
    import jax

    from fitting import engine, models, solve
    from fitting.solve import second_order

    jax.clear_caches()
    for cache in (solve.compiled_solver, second_order.curvature_program, solve.compiled_curvature,
                  engine.chunk_program, models.base._compiled_model,
                  models.network._four_compartment_moments_program):
        cache.cache_clear()
    gc.collect()


@pytest.fixture(autouse=True, scope="module")
def _bounded_mappings():
    yield
    held, limit = _mappings()
    if limit and held > _MAPPING_SHARE * limit:
        release_compiled_programs()


def pytest_unconfigure(config):
    if _OWNER:
        shutil.rmtree(_CACHE, ignore_errors=True)
        os.environ.pop(_SHARED, None)


def pytest_addoption(parser):
    parser.addoption("--studies", action="store_true", default=False,
                     help="also run the tests marked 'study' (minutes each; not run by CI)")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--studies"):
        return
    skip = pytest.mark.skip(reason="opt-in study: run with --studies")
    for item in items:
        if "study" in item.keywords:
            item.add_marker(skip)
