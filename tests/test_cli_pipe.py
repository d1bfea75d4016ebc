"""The command line piped into a reader that stops early (``axialmix fit ... | head``)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "data"


def test_a_reader_that_closes_the_pipe_early_loses_no_result(tmp_path):
    folder = tmp_path / "curves"
    folder.mkdir()
    for name in ("horizontal", "incline_plus14"):
        shutil.copy(EXAMPLES / f"{name}.csv", folder / f"{name}.csv")
    out = tmp_path / "out"
    # The reader takes one line of stdout and stderr together, then closes the pipe.
    program = f"{sys.executable} -c 'from fitting.cli import main; main()'"
    command = (f"{program} fit {folder} --model adm --out {out} 2>&1 "
               "| head -n 1; exit ${PIPESTATUS[0]}")
    done = subprocess.run(["bash", "-c", command], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Traceback" not in done.stdout + done.stderr
    written = sorted(p.name for p in out.iterdir())
    assert written == ["horizontal.json", "horizontal.png", "incline_plus14.json",
                       "incline_plus14.png", "summary.csv", "summary.json"]
