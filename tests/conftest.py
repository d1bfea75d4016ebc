import gc
import os
import shutil
import tempfile

import pytest

import axialmix  # noqa: F401  (float64 for every test)

# Each test process (and the command-line runs it starts) keeps its compiled programs in a
# cache folder of its own, removed at the end: the suite neither reads nor fills the user's
# cache, and the two test processes never share one (what processes sharing a cache do is
# tested on its own, in tests/test_compilation_cache.py).
_CACHE = tempfile.mkdtemp(prefix=f"axialmix-tests-{os.environ.get('PYTEST_XDIST_WORKER', 'main')}-")
os.environ["XDG_CACHE_HOME"] = _CACHE
os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
# ... and by default none at all (the crashes once blamed on the cache's serialisation were
# the mapping limit below; without the cache each test process compiles what it runs).
# Runs with the cache on are tested by tests/test_compilation_cache.py, in processes of
# their own. AXIALMIX_COMPILATION_CACHE=on in the environment keeps it on.
os.environ.setdefault("AXIALMIX_COMPILATION_CACHE", "off")


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
    shutil.rmtree(_CACHE, ignore_errors=True)


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
