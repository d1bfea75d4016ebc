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
# ... and by default none at all: in a test process that has compiled hundreds of programs,
# jaxlib's serialisation of an executable into the cache (and its deserialisation) has
# crashed the process (a segmentation fault inside XLA, seen twice, in different tests).
# Runs with the cache on are tested by tests/test_compilation_cache.py, in processes of
# their own. AXIALMIX_COMPILATION_CACHE=on in the environment keeps it on.
os.environ.setdefault("AXIALMIX_COMPILATION_CACHE", "off")


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
