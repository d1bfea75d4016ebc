"""Store the outputs of the documentation build in the notebooks, for readers of the repository.

The documentation build (``sphinx-build -W --keep-going -b html docs docs/_build/html``)
executes every notebook top to bottom and keeps the executed copies in
``docs/_build/jupyter_execute/notebooks/``. This script copies their outputs into
``notebooks/*.ipynb`` and records in each notebook's metadata a digest of its code cells
(``axialmix.code_digest``), so that ``tests/test_notebooks.py`` can tell stored outputs
that no longer belong to the code (a notebook edited after its outputs were stored).

Run it after a build from the repository root: ``python docs/store_notebook_outputs.py``.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import nbformat

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = ROOT / "notebooks"
EXECUTED = ROOT / "docs" / "_build" / "jupyter_execute" / "notebooks"


def code_digest(notebook) -> str:
    """SHA-256 of the notebook's code cells' sources, in order (outputs left out)."""
    digest = hashlib.sha256()
    for cell in notebook.cells:
        if cell.cell_type == "code":
            digest.update(cell.source.encode("utf-8") + b"\0")
    return digest.hexdigest()


def main() -> int:
    paths = sorted(NOTEBOOKS.glob("*.ipynb"))
    missing = [p.name for p in paths if not (EXECUTED / p.name).is_file()]
    if missing:
        print(f"store_notebook_outputs: no executed copy of {', '.join(missing)} in {EXECUTED}; "
              "build the documentation first", file=sys.stderr)
        return 2
    for path in paths:
        stored = nbformat.read(path, as_version=4)
        executed = nbformat.read(EXECUTED / path.name, as_version=4)
        if code_digest(stored) != code_digest(executed):
            print(f"store_notebook_outputs: {path.name} changed since the build; build again",
                  file=sys.stderr)
            return 2
        code = [c for c in stored.cells if c.cell_type == "code"]
        ran = [c for c in executed.cells if c.cell_type == "code"]
        for mine, theirs in zip(code, ran, strict=True):
            mine.outputs = theirs.outputs
            mine.execution_count = theirs.execution_count
        stored.metadata.setdefault("axialmix", {})["code_digest"] = code_digest(stored)
        nbformat.write(stored, path)
        print(f"{path.name}: outputs of {len(code)} code cells stored")
    return 0


if __name__ == "__main__":
    sys.exit(main())
