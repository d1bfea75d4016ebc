"""The model-comparison mode of ``axialmix fit`` (``--model adm,adm-exchange,tanks``): each
curve fitted with every model, one table comparing them (:func:`fitting.diagnostics.
compare_models`), each fit and the comparison written, and the summary of all curves.
"""

from __future__ import annotations

from axialmix._exits import BAD_INPUT, INTERRUPTED, OK, error_line
from fitting.cli.fit.curve import fit_one


class ComparisonMode:
    """The comparison part of a run of curve files (:class:`fitting.cli.fit.driver._Run`),
    which holds `args`, `out`, `compared` (``(model, settings)`` of each model), `stop`,
    `writing`, `status` and `records`."""

    def _compare(self, curve, path) -> int:
        """Fit one curve with every compared model; print and write the comparison."""
        from fitting.diagnostics import compare_models
        from fitting.report import (
            comparison_record,
            comparison_table,
            fit_record,
            render_fit_png,
            write_json,
            write_png,
        )

        args, out = self.args, self.out
        results, records = [], []
        for model, settings in self.compared:
            try:
                result = fit_one(model, curve, settings, args.loss,
                                 args.starts or model.default_starts,
                                 args.errors, self.stop)
            except ValueError as error:
                with self.writing:
                    self.status = error_line("fit", f"{path}: model {model.name}: {error}")
                return BAD_INPUT
            if self.stop.is_set():
                return INTERRUPTED
            results.append(result)
            records.append(fit_record(result, None, source=str(path), length_m=args.length))
        comparison = compare_models(results)
        record = comparison_record(comparison, records)
        record["source"] = str(path)
        images = [render_fit_png(result) for result in results]  # before the write lock
        with self.writing:
            if self.stop.is_set():
                return INTERRUPTED
            for result, fitted, image in zip(results, records, images, strict=True):
                write_json(out / f"{curve.name}.{result.model.name}.json", fitted)
                write_png(out / f"{curve.name}.{result.model.name}.png", image)
            write_json(out / f"{curve.name}.comparison.json", record)
            self.records.append(record)
        print(comparison_table(comparison, wide=self.args.wide), flush=True)
        return OK

    def _write_comparison_summary(self, records, interrupted: bool) -> None:
        from fitting.report import write_csv, write_json

        write_json(self.out / "summary.json", {
            "models": [m.name for m, _ in self.compared], "loss_name": self.args.loss,
            "complete": not interrupted,
            "comparisons": [{k: v for k, v in r.items() if k != "fits"} for r in records]})
        header = ["curve", "model", "sse", "aicc", "delta_aicc", "bic", "systematic_misfit",
                  "converged", "recommended"]
        rows = [[r["data"], m["model"], m["sse"], m["aicc"], m["delta_aicc"], m["bic"],
                 m["lack_of_fit"]["systematic"], m["converged"], m["model"] == r["best"]]
                for r in records for m in r["models"]]
        write_csv(self.out / "summary.csv", header, rows)
