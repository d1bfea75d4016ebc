"""Deprecated: the ``axialmix simulate`` command moved to :mod:`fitting.cli.simulate`.

Only :func:`write_json_atomically` is left here, for one release; use
:func:`axialmix._files.write_json`.
"""

from __future__ import annotations

from axialmix._deprecation import deprecated_alias
from axialmix._files import write_json

__all__ = ["write_json_atomically"]

write_json_atomically = deprecated_alias(
    write_json, "axialmix.particles.cli.write_json_atomically", "axialmix._files.write_json"
)
