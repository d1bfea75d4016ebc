"""The packages are one-way houses: each fitting module imports only the layers before it.

The test reads the source (AST), so it needs no imports of the packages themselves.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The layers of ``fitting``, in order: a module may import only modules listed before it
#: (and anything of ``axialmix``). The package face ``fitting/__init__.py`` loads names lazily.
FITTING_LAYERS = (
    "fitting.distributions",
    "fitting.drawing",
    "fitting.parameters",
    "fitting.losses",
    "fitting.data",
    "fitting.models",
    "fitting.measurement",
    "fitting.solve",
    "fitting.uncertainty",
    "fitting.residuals",
    "fitting.result",
    "fitting.physical",
    "fitting.fit",
    "fitting.diagnostics",
    "fitting.gridsearch",
    "fitting.study",
    "fitting.report",
    "fitting.study.batch",  # renders each curve through fitting.report
    "fitting.study.ensemble",
    "fitting.cli.anova",
    "fitting.cli.fit",
    "fitting.cli.simulate",
    "fitting.cli.globalfit",
    "fitting.cli.funnel",
    "fitting.cli.divert",
    "fitting.cli.dem",
    "fitting.cli",
    # Deprecated aliases of earlier releases, kept one release: they sit on top.
    "fitting.io",
    "fitting.objective",
    "fitting.optimize",
    "fitting.fitcli",
)
#: Deprecated names forwarded upward on first use (``importlib``), kept one release.
DEPRECATED_FORWARDS = {
    ("fitting.uncertainty", "fitting.diagnostics"),
    ("fitting.result", "fitting.diagnostics"),
}
#: Optional or heavy third-party packages a fitting module may import inside a function.
OPTIONAL_HEAVY = ("matplotlib", "statsmodels", "pandas", "dask", "optax")
IN_FUNCTION_MODULES = ("fitting.cli",)  # the command line loads what a sub-command needs


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _sources() -> dict[str, tuple[Path, ast.Module]]:
    sources = {}
    for package in ("axialmix", "fitting"):
        for path in sorted((ROOT / package).rglob("*.py")):
            sources[_module_name(path)] = (path, ast.parse(path.read_text(), str(path)))
    return sources


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str, path: Path, tree: ast.Module):
    """``(imported module, names, line, inside a function)`` of every import, including
    ``importlib.import_module("...")`` calls with a constant name."""
    is_package = path.name == "__init__.py"
    found = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef |
                                              ast.Lambda)
            if isinstance(child, ast.Import):
                for alias in child.names:
                    found.append((alias.name, (), child.lineno, in_function))
            elif isinstance(child, ast.ImportFrom):
                target = _resolve(module, is_package, child)
                found.append((target, tuple(a.name for a in child.names), child.lineno,
                              in_function))
            elif (isinstance(child, ast.Call) and isinstance(child.func, ast.Attribute)
                  and child.func.attr == "import_module" and child.args
                  and isinstance(child.args[0], ast.Constant)
                  and isinstance(child.args[0].value, str)):
                found.append((child.args[0].value, (), child.lineno, True))
            visit(child, inner)

    visit(tree, False)
    return found


def _layer(module: str) -> int | None:
    best = None
    for index, layer in enumerate(FITTING_LAYERS):
        if module == layer or module.startswith(layer + "."):
            if best is None or len(layer) > len(FITTING_LAYERS[best]):
                best = index
    return best


def layering_violations(sources) -> list[str]:
    """Every upward import, cross-module private import, in-function import and import of
    ``fitting`` by ``axialmix``, as ``file:line: problem``."""
    problems = []
    for module, (path, tree) in sources.items():
        where = path.relative_to(ROOT)
        own_layer = _layer(module)
        for target, names, line, in_function in _imports(module, path, tree):
            at = f"{where}:{line}"
            if module.startswith("axialmix") and target.split(".")[0] == "fitting":
                problems.append(f"{at}: axialmix imports {target}")
            private = [n for n in names if n.startswith("_") and not n.startswith("__")
                       and f"{target}.{n}" not in sources]  # a private module is plumbing
            # Private helpers shared by the private modules of one axialmix subpackage are
            # that subpackage's business; across subpackages, and anywhere in fitting, not.
            same_package = (module.startswith("axialmix.") and target.rsplit(".", 1)[0]
                            == module.rsplit(".", 1)[0] or target == module.rsplit(".", 1)[0])
            if private and target != module and not same_package:
                problems.append(f"{at}: imports private name(s) {', '.join(private)} of "
                                f"{target}")
            if not module.startswith("fitting") or module == "fitting":
                continue
            if target.split(".")[0] == "fitting" and target != "fitting":
                layer = _layer(target)
                upward = layer is None or own_layer is None or layer >= own_layer
                face = layer == own_layer and target.startswith(module + ".")  # a package face
                if upward and not face and (module, target) not in DEPRECATED_FORWARDS and not (
                        module == "fitting.cli" and target.startswith("fitting.cli.")):
                    problems.append(f"{at}: {module} imports {target}, which is not a layer "
                                    "before it")
            heavy = target.split(".")[0] in OPTIONAL_HEAVY
            if in_function and not heavy and not module.startswith(IN_FUNCTION_MODULES) and (
                    module, target) not in DEPRECATED_FORWARDS:
                problems.append(f"{at}: import of {target} inside a function")
    return problems


def test_every_fitting_module_has_a_layer():
    sources = _sources()
    unplaced = [m for m in sources if m.startswith("fitting.") and _layer(m) is None]
    assert unplaced == []


def test_imports_go_one_way_with_no_private_names_across_modules():
    problems = layering_violations(_sources())
    assert problems == [], "\n".join(problems)


def test_the_check_sees_an_upward_import(tmp_path):
    sources = _sources()
    path, tree = sources["fitting.parameters"]
    upward = ast.parse("from fitting.fit import fit\n")
    tree = ast.Module(body=[*upward.body, *tree.body], type_ignores=[])
    problems = layering_violations({**sources, "fitting.parameters": (path, tree)})
    assert any("fitting.parameters imports fitting.fit" in p for p in problems)


@pytest.mark.parametrize("snippet, words", [
    ("from fitting.solve import _RUNNING\n", "private name(s) _RUNNING"),
    ("def f():\n    import fitting.losses\n", "inside a function"),
])
def test_the_check_sees_private_and_in_function_imports(snippet, words):
    sources = _sources()
    path, tree = sources["fitting.result"]
    extra = ast.parse(snippet)
    tree = ast.Module(body=[*extra.body, *tree.body], type_ignores=[])
    problems = layering_violations({**sources, "fitting.result": (path, tree)})
    assert any(words in p for p in problems), problems
