"""Process-factor analysis: analysis of variance of a response over the factors of a study.

A study table has one row per run: factor columns (categorical such as ``angle``, or numeric
such as ``rpm``) and response columns (a measured quantity, or a parameter fitted to the
run's RTD). :func:`anova` partitions the variation of one response among the factors and
their interactions, by ordinary least squares fits of nested linear models (statsmodels),
and returns an immutable :class:`AnovaTable`.

Sums of squares. In a balanced design (every combination of factor levels run equally
often) the sequential (type I), hierarchical (type II) and marginal (type III) sums of
squares coincide. In an unbalanced design they differ; the default is type II (each term
adjusted for every term that does not contain it), which tests main effects without
assuming the interactions are absent and respects marginality. The table says which type
it used.

Estimability. A term is tested only as far as the design can estimate it: its degrees of
freedom are the rank it adds to the design matrix. An interaction of factors that were never
crossed (for example angles varied at one speed only, speeds varied at one angle only) adds
no rank; it is left out of the table and named in :attr:`AnovaTable.not_estimable`.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from axialmix._csv import DataError, read_table

__all__ = ["AnovaSource", "AnovaTable", "anova", "is_balanced", "read_study_table"]

_SS_TYPES = (1, 2, 3)


@dataclass(frozen=True)
class AnovaSource:
    """One row of an ANOVA table.

    **Fields:** `source` (a factor ``"A"``, an interaction ``"A:B"``, or ``"error"``), `df`
    (degrees of freedom), `ss` (sum of squares, in the response's unit squared), `ms` (mean
    square, ``ss / df``), `F` (``ms / ms_error``; ``None`` for the error row) and `p` (the
    probability of an F at least this large when the term has no effect; ``None`` for the
    error row).
    """

    source: str
    df: int
    ss: float
    ms: float
    F: float | None = None
    p: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The row as a JSON-ready mapping with keys source, df, ss, ms, F, p."""
        return {"source": self.source, "df": self.df, "ss": self.ss, "ms": self.ms,
                "F": self.F, "p": self.p}


@dataclass(frozen=True)
class AnovaTable:
    """An analysis of variance of one response over the factors of a study.

    **Fields:**

    - `response`: the response column analysed.
    - `factors`: the factor columns, in the order given.
    - `numeric`: the factors treated as numeric (one degree of freedom, a linear trend).
    - `sources`: the rows, terms in model order then ``"error"``.
    - `ss_type`: 1, 2 or 3 (see the module docstring).
    - `balanced`: whether every cell of the categorical factors has the same number of runs.
    - `n_runs`: rows used.
    - `not_estimable`: interaction terms the design cannot estimate (left out).
    - `formula`: the full model, in statsmodels' formula language.
    """

    response: str
    factors: tuple[str, ...]
    numeric: tuple[str, ...]
    sources: tuple[AnovaSource, ...]
    ss_type: int
    balanced: bool
    n_runs: int
    not_estimable: tuple[str, ...] = field(default=())
    formula: str = ""

    def source(self, name: str) -> AnovaSource:
        """The row called `name` (``"A"``, ``"A:B"`` or ``"error"``)."""
        for row in self.sources:
            if row.source == name:
                return row
        raise KeyError(f"no source {name!r} in this table; it has "
                       f"{', '.join(r.source for r in self.sources)}")

    @property
    def statement(self) -> str:
        """One paragraph on the design and the sums of squares used."""
        if self.balanced:
            kind = "balanced design: type I, II and III sums of squares coincide"
        else:
            names = {1: "type I (sequential, in the order the terms are listed)",
                     2: "type II (each term adjusted for all terms not containing it)",
                     3: "type III (each term adjusted for all others, sum-to-zero contrasts)"}
            kind = f"unbalanced design: {names[self.ss_type]} sums of squares"
        text = f"{self.n_runs} runs, {kind}."
        if self.not_estimable:
            text += (f" Not estimable from this design (factors never crossed), left out: "
                     f"{', '.join(self.not_estimable)}.")
        return text

    def to_dict(self) -> dict[str, Any]:
        """The table as a JSON-ready mapping: ``{"sources": [...], ...}``."""
        return {
            "response": self.response,
            "factors": list(self.factors),
            "numeric_factors": list(self.numeric),
            "ss_type": self.ss_type,
            "balanced": self.balanced,
            "n_runs": self.n_runs,
            "not_estimable": list(self.not_estimable),
            "formula": self.formula,
            "statement": self.statement,
            "sources": [row.to_dict() for row in self.sources],
        }

    def report(self) -> str:
        """The table as aligned text, with the design statement underneath."""
        header = ("source", "df", "SS", "MS", "F", "p")
        rows = [(r.source, str(r.df), f"{r.ss:.6g}", f"{r.ms:.6g}",
                 "" if r.F is None else f"{r.F:.4g}", "" if r.p is None else f"{r.p:.4g}")
                for r in self.sources]
        widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(header)]
        lines = ["  ".join(h.ljust(w) if i == 0 else h.rjust(w)
                           for i, (h, w) in enumerate(zip(header, widths, strict=True)))]
        for row in rows:
            lines.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w)
                                   for i, (c, w) in enumerate(zip(row, widths, strict=True))))
        return "\n".join([f"ANOVA of {self.response}", *lines, self.statement])


def is_balanced(table: Mapping[str, Sequence[Any]], factors: Sequence[str]) -> bool:
    """Whether every combination of the factors' levels occurs equally often (at least once).

    **Arguments:** `table`, columns by name; `factors`, the factor column names.

    **Returns:** ``True`` for a complete design with equal replication.
    """
    columns = [list(table[f]) for f in factors]
    levels = [sorted(set(c), key=str) for c in columns]
    counts: dict[tuple, int] = {}
    for cell in zip(*columns, strict=True):
        counts[cell] = counts.get(cell, 0) + 1
    n_cells = math.prod(len(level) for level in levels)
    return len(counts) == n_cells and len(set(counts.values())) == 1


def read_study_table(path: str | Path, columns: Sequence[str]) -> dict[str, list[str]]:
    """Read the named columns of a study table (one row per run) as text cells.

    **Arguments:**

    - `path`: a CSV file with a header row (``#`` comment lines allowed; delimiter detected
      as for curves, see :mod:`axialmix._csv`).
    - `columns`: the column names wanted (case-insensitive; a unit in the header is allowed).

    **Returns:** ``{name: [cell, ...]}`` in the order of the rows, names as given.

    **Raises:** :class:`axialmix._csv.DataError` (one line, file and row) for a missing
    column, a ragged row, an empty cell or an unreadable file.
    """
    table = read_table(path, header=True)
    found = [table.column(name) for name in columns]
    out: dict[str, list[str]] = {name: [] for name in columns}
    for number, cells in table.rows():
        for name, column in zip(columns, found, strict=True):
            cell = cells[column.index].strip().strip('"').strip()
            if cell == "":
                raise DataError(table.path, f"empty cell in column {column.label!r}", number)
            out[name].append(cell)
    if not out[columns[0]]:
        raise DataError(table.path, "no data rows under the header")
    return out


def _term_name(factors: tuple[str, ...]) -> str:
    return ":".join(factors)


def _quoted(name: str) -> str:
    return f"Q({name!r})"


def _encode(name: str, numeric: set[str], ss_type: int) -> str:
    if name in numeric:
        return _quoted(name)
    return f"C({_quoted(name)}, Sum)" if ss_type == 3 else f"C({_quoted(name)})"


def _formula_term(term: tuple[str, ...], numeric: set[str], ss_type: int) -> str:
    return ":".join(_encode(f, numeric, ss_type) for f in term)


def _fit(frame, response: str, terms: Sequence[tuple[str, ...]], numeric: set[str],
         ss_type: int):
    import statsmodels.formula.api as smf
    from statsmodels.tools.sm_exceptions import SingularMatrixWarning

    right = " + ".join(_formula_term(t, numeric, ss_type) for t in terms) or "1"
    with warnings.catch_warnings():
        # Expected while probing whether a term adds rank; the rank is what is used.
        warnings.simplefilter("ignore", SingularMatrixWarning)
        return smf.ols(f"{_quoted(response)} ~ {right}", frame).fit()


def _rank(result) -> int:
    return int(round(result.df_model)) + int(result.k_constant)


def anova(
    table: Mapping[str, Sequence[Any]],
    response: str,
    factors: Sequence[str],
    *,
    interactions: int = 1,
    numeric: Sequence[str] = (),
    ss_type: int | None = None,
) -> AnovaTable:
    """Analysis of variance of `response` over `factors` and their interactions.

    **Arguments:**

    - `table`: the study, columns by name (a mapping of sequences or a pandas DataFrame),
      one row per run.
    - `response`: the column to analyse (numbers, in any unit).
    - `factors`: the factor columns; categorical unless named in `numeric`.
    - `interactions`: the highest order of interaction included: 1 for main effects only,
      2 for all two-way interactions, and so on (at most ``len(factors)``).
    - `numeric`: factors entered as a linear trend (one degree of freedom) rather than as
      categories.
    - `ss_type`: 1, 2 or 3; ``None`` (default) uses type II (identical to the others when
      the design is balanced).

    **Returns:** an :class:`AnovaTable`.

    **Raises:** `ValueError` (one line) for a missing column, a non-numeric response, a
    factor with a single level, or a model that leaves no degrees of freedom for error.
    """
    import pandas as pd

    factors = tuple(factors)
    numeric_set = set(numeric)
    if not factors:
        raise ValueError("give at least one factor")
    if len(set(factors)) != len(factors):
        raise ValueError(f"factors listed twice: {', '.join(factors)}")
    unknown = [n for n in numeric if n not in factors]
    if unknown:
        raise ValueError(f"numeric factor {unknown[0]!r} is not among the factors")
    if not 1 <= interactions <= len(factors):
        raise ValueError(f"interactions must be between 1 and {len(factors)} (the number of "
                         f"factors), got {interactions}")
    ss_type = 2 if ss_type is None else int(ss_type)
    if ss_type not in _SS_TYPES:
        raise ValueError(f"ss_type must be 1, 2 or 3, got {ss_type}")
    frame = pd.DataFrame({name: list(table[name]) for name in table.keys()}) \
        if not isinstance(table, pd.DataFrame) else table.copy()
    for name in (response, *factors):
        if name not in frame.columns:
            raise ValueError(f"no column {name!r}; the table has "
                             f"{', '.join(map(str, frame.columns))}")
    values = pd.to_numeric(frame[response], errors="coerce")
    bad = np.flatnonzero(~np.isfinite(values.to_numpy(dtype=float)))
    if bad.size:
        raise ValueError(f"response {response!r} is not a finite number in run {bad[0] + 1}: "
                         f"{frame[response].iloc[bad[0]]!r}")
    frame[response] = values.astype(float)
    for name in factors:
        if name in numeric_set:
            column = pd.to_numeric(frame[name], errors="coerce")
            if column.isna().any():
                row = int(np.flatnonzero(column.isna().to_numpy())[0])
                raise ValueError(f"numeric factor {name!r} is not a number in run {row + 1}: "
                                 f"{frame[name].iloc[row]!r}")
            frame[name] = column.astype(float)
        else:
            frame[name] = frame[name].astype(str)
        if frame[name].nunique() < 2:
            raise ValueError(f"factor {name!r} has a single level; it explains nothing")

    categorical = [f for f in factors if f not in numeric_set]
    balanced = bool(categorical) and not numeric_set and is_balanced(frame, categorical)

    # Terms in hierarchical order; keep an interaction only where it adds rank.
    candidates = [t for order in range(1, interactions + 1)
                  for t in itertools.combinations(factors, order)]
    terms: list[tuple[str, ...]] = []
    not_estimable: list[str] = []
    rank = _rank(_fit(frame, response, [], numeric_set, ss_type))
    for term in candidates:
        trial = _fit(frame, response, [*terms, term], numeric_set, ss_type)
        if _rank(trial) > rank:
            terms.append(term)
            rank = _rank(trial)
        else:
            not_estimable.append(_term_name(term))

    full = _fit(frame, response, terms, numeric_set, ss_type)
    df_error = int(round(full.df_resid))
    if df_error <= 0:
        raise ValueError(
            f"the model with interactions up to order {interactions} uses every degree of "
            f"freedom of the {len(frame)} runs, leaving none for error; lower --interactions"
        )
    ss_error = float(full.ssr)
    ms_error = ss_error / df_error

    rows = []
    for index, term in enumerate(terms):
        if ss_type == 1:
            reduced_terms = terms[:index]
        elif ss_type == 2:
            reduced_terms = [t for t in terms if t != term and not set(term) <= set(t)]
        else:
            reduced_terms = [t for t in terms if t != term]
        with_term = reduced_terms + [term] if ss_type != 3 else terms
        bigger = _fit(frame, response, with_term, numeric_set, ss_type)
        smaller = _fit(frame, response, reduced_terms, numeric_set, ss_type)
        df = _rank(bigger) - _rank(smaller)
        ss = max(float(smaller.ssr - bigger.ssr), 0.0)
        ms = ss / df if df else float("nan")
        f_value = ms / ms_error if ms_error > 0 else float("inf")
        p = float(stats.f.sf(f_value, df, df_error))
        rows.append(AnovaSource(_term_name(term), df, ss, ms, f_value, p))
    rows.append(AnovaSource("error", df_error, ss_error, ms_error))
    formula = f"{response} ~ " + " + ".join(_formula_term(t, numeric_set, ss_type)
                                            for t in terms)
    return AnovaTable(
        response=response, factors=factors, numeric=tuple(n for n in factors
                                                          if n in numeric_set),
        sources=tuple(rows), ss_type=ss_type, balanced=balanced, n_runs=len(frame),
        not_estimable=tuple(not_estimable), formula=formula,
    )
