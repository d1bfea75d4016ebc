"""What ``axialmix fit`` prints for a single curve: its table of values, standard errors and
intervals, why a fit did not converge, what the data determine, the error model and the
equivalent ADM.
"""

from __future__ import annotations


def print_single(result, grid, record, fit_table, length: float | None = None) -> None:
    print(fit_table(result, grid, length))
    if not result.converged:  # why, first: the table says only "no"
        print(f"  * {result.message[0].upper()}{result.message[1:]}.")
    for sentence in record["identifiability"]:
        print(f"  * {sentence}")
    for name, meaning in record.get("meanings", {}).items():
        if name in ("tau", "amplitude") and name in result.values:
            print(f"  * {meaning[0].upper()}{meaning[1:]}.")
    if result.error_model is not None:
        unit = result.curve.value_unit or ""
        print(f"  * Errors: {result.error_model.describe(unit)}.")
    equivalent = record.get("equivalent_adm")
    if equivalent is not None and "variance_ratio" in equivalent:
        unit = result.time_unit
        length = equivalent["length_m"]
        transport = ("" if length is None else
                     f", v = {_show(equivalent['velocity_m_per_s'])} m/s, D_z = "
                     f"{_show(equivalent['dispersion_m2_per_s'])} m^2/s (L = {length:g} m)")
        print("  equivalent closed-closed ADM (same mean and variance): tau = "
              f"{_show(equivalent[f'tau_{unit}'])} {unit}, Pe = {_show(equivalent['peclet'])}"
              f"{transport}")


def _show(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"
