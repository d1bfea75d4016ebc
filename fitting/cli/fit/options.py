"""The options of ``axialmix fit`` checked and turned into what the fit needs.

``--model`` (built-in names or network files, several to compare), ``--fix`` and ``--tie``
(parameter settings checked against each model), ``--free``, ``--profile``, the column
options and the error model ``--errors`` chooses (or the input's kind implies). A bad value
raises :class:`InputError`, one line without the program prefix.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path


class InputError(Exception):
    """Bad command-line input; the message is one line, without the program prefix."""


def _model(name: str):
    from fitting.models import MODELS, network_model

    if name in MODELS:
        return MODELS[name]
    path = Path(name)
    if path.suffix.lower() in (".json", ".toml"):
        if not path.is_file():
            raise InputError(f"{path}: network file not found")
        try:
            return network_model(path)
        except (ValueError, KeyError, TypeError, OSError, AttributeError) as error:
            raise InputError(f"{path}: {' '.join(str(error).split())}") from None
    raise InputError(f"--model: unknown model {name!r}; choose one of {', '.join(MODELS)} "
                     "or give a network file (.json or .toml)")


def models_named(text: str) -> list:
    """The models of ``--model``: one name, or several separated by commas (to compare)."""
    names = [name.strip() for name in text.split(",")]
    if len(names) > 1 and not all(names):
        raise InputError(f"--model: empty name in {text!r}; separate model names by commas")
    models = [_model(name) for name in names]
    seen = set()
    for model in models:
        if model.name in seen:
            raise InputError(f"--model: {model.name!r} is given twice")
        seen.add(model.name)
    return models


def settings_for_each(models, fixes: Sequence[str], ties: Sequence[str]) -> list[dict]:
    """--fix and --tie settings of each compared model: an option applies to the models that
    have every parameter it names, and must apply to at least one."""
    if len(models) == 1:
        return [parameter_settings(models[0], fixes, ties)]
    for option, items in (("--fix", fixes), ("--tie", ties)):
        for name, value in _pairs(items, option):
            labels = {name} if option == "--fix" else {name, value}
            if not any(labels <= set(m.parameter_names) for m in models):
                raise InputError(f"{option}: no compared model has {' and '.join(sorted(labels))}"
                                 f" ({', '.join(m.name for m in models)})")

    from fitting.parameters import canonical_name

    def applies(model, item: str, option: str) -> bool:
        name, _, value = item.partition("=")
        name, value = canonical_name(name.strip()), canonical_name(value.strip())
        labels = {name} if option == "--fix" else {name, value}
        return labels <= set(model.parameter_names)

    return [parameter_settings(m, [f for f in fixes if applies(m, f, "--fix")],
                               [t for t in ties if applies(m, t, "--tie")]) for m in models]


def _pairs(items: Sequence[str], option: str) -> list[tuple[str, str]]:
    from fitting.parameters import canonical_name

    pairs = []
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise InputError(f"{option}: expected NAME=VALUE, got {item!r}")
        value = canonical_name(value.strip()) if option == "--tie" else value.strip()
        pairs.append((canonical_name(name.strip()), value))
    return pairs


def parameter_settings(model, fixes: Sequence[str], ties: Sequence[str]) -> dict:
    """Parameter settings for --fix and --tie, checked against the model."""
    settings = {}
    for name, text in _pairs(fixes, "--fix"):
        if name not in model.parameter_names:
            raise InputError(f"--fix: model {model.name!r} has no parameter {name!r} "
                             f"(it has {', '.join(model.parameter_names)})")
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"--fix {name}: {text!r} is not a number") from None
        default = model.defaults[name]
        signed = default.min is None  # a baseline or dead time may be negative
        if not math.isfinite(value) or (value < 0 and not signed) or abs(value) > 1e100:
            raise InputError(f"--fix {name}: value must be a finite non-negative number of "
                             f"sensible size, got {text}")
        if value == 0 and default.min is not None and default.min >= 0:
            raise InputError(f"--fix {name}: must be positive, got {text} (the model is "
                             f"undefined or has no outflow at {name} = 0)")
        settings[name] = default.replace(value=value, vary=False, expr=None)
    for name, other in _pairs(ties, "--tie"):
        for label in (name, other):
            if label not in model.parameter_names:
                raise InputError(f"--tie: model {model.name!r} has no parameter {label!r} "
                                 f"(it has {', '.join(model.parameter_names)})")
        if name == other or name in settings:
            raise InputError(f"--tie {name}={other}: a parameter cannot be tied to itself or "
                             "be both fixed and tied")
        settings[name] = model.defaults[name].replace(expr=other)
    free = [n for n in model.parameter_names if n not in settings]
    if not free:
        raise InputError("--fix/--tie: nothing left to fit: every parameter is fixed or tied")
    return settings


def column_key(text: str | None) -> str | int | None:
    """A ``--time-column``/``--value-column`` value: a 0-based index when all digits."""
    if text is None:
        return None
    return int(text) if text.strip().isdigit() else text.strip()


def free_names(items: Sequence[str]) -> tuple[str, ...]:
    """The measurement parameters of ``--free`` (comma-separated or repeated; t_d, b allowed)."""
    from fitting.measurement import FREEABLE
    from fitting.parameters import canonical_name

    names = []
    for item in items:
        for name in item.split(","):
            name = canonical_name(name.strip())
            if name not in FREEABLE:
                raise InputError(f"--free: unknown measurement parameter {name!r}; choose "
                                 f"from {', '.join(FREEABLE)} (or t_d, b)")
            names.append(name)
    return tuple(dict.fromkeys(names))


def default_errors(args: argparse.Namespace, curves: Sequence | None) -> str:
    """The error model: ``--errors`` when given; else counting errors for files of particle
    counts (said in one line), absolute errors with ``--grid``, combined ones otherwise."""
    counting = [] if curves is None else [c.exposure is not None for c in curves]
    if args.errors is not None:
        if args.errors != "poisson" and any(counting):
            names = ", ".join(c.source or c.name for c, k in zip(curves, counting, strict=True)
                              if k)
            print(f"axialmix fit: warning: {names} hold(s) particle counts, fitted with "
                  f"--errors {args.errors} as asked; their noise is Poisson (--errors poisson)",
                  file=sys.stderr)
        return args.errors
    if counting and all(counting):
        if args.grid:
            raise InputError("--grid scores the unweighted loss; these files hold particle "
                             "counts, whose noise is Poisson: fit them without --grid")
        files = ", ".join(c.source or c.name for c in curves)
        print(f"counting errors: {files} hold{'s' if len(curves) == 1 else ''} particle counts "
              "(Poisson noise of known size), fitted by maximum likelihood (--errors poisson)")
        return "poisson"
    if any(counting):
        listed = ", ".join(c.source or c.name for c, k in zip(curves, counting, strict=True) if k)
        raise InputError(f"{listed} hold particle counts and the other files signals: fit them "
                         "apart, or choose one error model with --errors")
    return "absolute" if args.grid else "combined"


def profile_names(text: str, model, settings: dict) -> tuple[str, ...] | None:
    """The parameters ``--profile`` names (``None``: every free one), checked up front."""
    if text.strip() == "all":
        return None
    from fitting.parameters import canonical_name

    names = tuple(dict.fromkeys(canonical_name(n.strip()) for n in text.split(",")
                                if n.strip()))
    known = model.parameter_names
    for name in names:
        if name not in known:
            raise InputError(f"--profile: {name!r} is not a parameter of {model.name} "
                             f"({', '.join(known)})")
        setting = settings.get(name)
        if setting is not None and (not setting.vary or setting.expr is not None):
            raise InputError(f"--profile: {name} is fixed or tied; profile a free parameter")
    if not names:
        raise InputError("--profile: name at least one parameter (or none, for all)")
    return names
