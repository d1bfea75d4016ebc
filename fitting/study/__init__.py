"""Studies of many curves: process-factor analysis of a table of runs."""

from fitting.study.anova import AnovaSource, AnovaTable, anova, is_balanced, read_study_table
from fitting.study.global_fit import (
    FactorLaw,
    GlobalFitResult,
    GlobalModel,
    GlobalProblem,
    LawEstimate,
    global_fit,
    global_problem,
    two_stage_law,
)
from fitting.study.input import Study, factor_value, read_design, read_long_csv, study_from_files

__all__ = ["AnovaSource", "AnovaTable", "anova", "is_balanced", "read_study_table"]
__all__ += ["FactorLaw", "GlobalFitResult", "GlobalModel", "GlobalProblem", "LawEstimate",
            "global_fit", "global_problem", "two_stage_law"]
__all__ += ["Study", "factor_value", "read_design", "read_long_csv", "study_from_files"]
