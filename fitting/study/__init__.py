"""Studies of many curves: process-factor analysis of a table of runs."""

from fitting.study.anova import AnovaSource, AnovaTable, anova, is_balanced, read_study_table

__all__ = ["AnovaSource", "AnovaTable", "anova", "is_balanced", "read_study_table"]
