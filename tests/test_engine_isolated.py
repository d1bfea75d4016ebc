"""tests/test_engine.py in a process of its own (see there why), as part of the suite."""

import os
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.skipif(not os.environ.get("PYTEST_XDIST_WORKER"),
                    reason="without workers tests/test_engine.py runs in this process")
def test_the_engine_tests_pass_in_a_process_of_their_own():
    here = Path(__file__).resolve().parent
    env = {**os.environ, "AXIALMIX_ISOLATED": "1"}
    env.pop("PYTEST_XDIST_WORKER", None)
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           str(here / "test_engine.py")], capture_output=True, text=True,
                          env=env, cwd=here.parent, timeout=1800)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
