import pytest

import axialmix  # noqa: F401  (float64 for every test)


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
