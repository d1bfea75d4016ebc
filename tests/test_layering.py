"""The packages are one-way houses: each fitting module imports only the layers before it.

The test reads the source (AST), so it needs no imports of the packages themselves. Imports by
name count as imports: ``importlib.import_module("...")`` (also under another name, relative
with ``package=``, or with the name built from constants, ``__name__`` and ``__package__``),
``__import__("...")`` and ``importlib.util.find_spec("...")``. A name the check cannot read is
allowed only in a package face (``__init__.py``), and there every project module named by a
string in the file counts as imported.

Run as a script, it prints the import drawing of ``fitting`` (one ``module -> module`` edge a
line) and whether it has a circle.
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
    "fitting.models.base",  # the models, one concept a module, then their face
    "fitting.models.moments",
    "fitting.models.inlet",
    "fitting.models.adm",
    "fitting.models.exchange",
    "fitting.models.network",
    "fitting.models.registry",
    "fitting.models",
    "fitting.measurement",
    "fitting.solve.status",  # the optimiser core, one concept a module, then its face
    "fitting.solve.settings",
    "fitting.solve.padding",
    "fitting.solve.programs",
    "fitting.solve.first_order",
    "fitting.solve.levenberg_marquardt",
    "fitting.solve.single_start",
    "fitting.solve.second_order",
    "fitting.solve.multistart",
    "fitting.solve",
    "fitting.engine",
    "fitting.uncertainty",
    "fitting.residuals",
    "fitting.result",
    "fitting.physical",
    "fitting.optima",
    "fitting.fit",
    "fitting.diagnostics",
    "fitting.gridsearch",
    "fitting.study.global_fit.law",  # the global fit, one concept a module, then its face
    "fitting.study.global_fit.model",
    "fitting.study.global_fit.joint",
    "fitting.study.global_fit.problem",
    "fitting.study.global_fit.estimate",
    "fitting.study.global_fit.result",
    "fitting.study.global_fit.propagation",
    "fitting.study.global_fit.solver",
    "fitting.study.global_fit",
    "fitting.study",
    "fitting.report",
    "fitting.study.batch",  # renders each curve through fitting.report
    "fitting.study.ensemble",
    "fitting.cli._outputs",  # the output convention every sub-command writes by
    "fitting.cli.anova",
    "fitting.cli.fit.options",  # the fit sub-command, one concept a module, then its face
    "fitting.cli.fit.inputs",
    "fitting.cli.fit.outfolder",
    "fitting.cli.fit.supervise",
    "fitting.cli.fit.curve",
    "fitting.cli.fit.report",
    "fitting.cli.fit.compare",
    "fitting.cli.fit.study",
    "fitting.cli.fit.driver",
    "fitting.cli.fit",
    "fitting.cli.simulate",
    "fitting.cli.globalfit",
    "fitting.cli.funnel",
    "fitting.cli.divert",
    "fitting.cli.dem",
    "fitting.cli",
)
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


#: Functions that import the module named by their first argument.
_BY_NAME = {"import_module", "__import__", "find_spec"}
#: What stands for the module's own name (``__name__``) or package (``__package__``).
_OWN_NAMES = ("__name__", "__package__")


def _name_of(node, module: str, is_package: bool) -> str | None:
    """The string `node` evaluates to when it is built from constants, ``__name__`` and
    ``__package__`` (joined with ``+`` or in an f-string); ``None`` otherwise."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.Name) and node.id in _OWN_NAMES:
        return module if node.id == "__name__" or is_package else module.rpartition(".")[0]
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        left, right = (_name_of(n, module, is_package) for n in (node.left, node.right))
        return None if left is None or right is None else left + right
    if isinstance(node, ast.JoinedStr):
        parts = [_name_of(v.value if isinstance(v, ast.FormattedValue) else v, module,
                          is_package) for v in node.values]
        return None if None in parts else "".join(parts)
    return None


def _by_name(call: ast.Call, module: str, is_package: bool, importers: set[str]):
    """``(is an import by name, the module's name or None)`` of a call."""
    func = call.func
    called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if called not in _BY_NAME and called not in importers:
        return False, None
    if not call.args:
        return True, None
    name = _name_of(call.args[0], module, is_package)
    package = next((k.value for k in call.keywords if k.arg == "package"), None)
    if name is not None and name.startswith("."):  # relative: needs its package
        anchor = None if package is None else _name_of(package, module, is_package)
        if anchor is None:
            return True, None
        level = len(name) - len(name.lstrip("."))
        base = anchor.split(".")
        base = base[: len(base) - (level - 1)]
        name = ".".join(base + ([name.lstrip(".")] if name.lstrip(".") else []))
    return True, name


def _imports(module: str, path: Path, tree: ast.Module):
    """``(imported module, names, line, inside a function)`` of every import, including
    imports by name (``importlib.import_module``, ``__import__``, ``find_spec``); the module
    is ``None`` where the name cannot be read from the source."""
    is_package = path.name == "__init__.py"
    found = []
    # Local names of importlib's import_module and find_spec (``from importlib import ...``).
    importers = {alias.asname or alias.name for node in ast.walk(tree)
                 if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                     "importlib") for alias in node.names if alias.name in _BY_NAME}

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
            elif isinstance(child, ast.Call):
                is_import, target = _by_name(child, module, is_package, importers)
                if is_import:
                    found.append((target, (), child.lineno, in_function))
            visit(child, inner)

    visit(tree, False)
    return found


def _named_modules(module: str, tree: ast.Module, sources) -> list[str]:
    """The project modules a package face may import by a name it builds: every string in
    the file that is a module's name, alone or after the face's own name."""
    named = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            for candidate in (node.value, f"{module}.{node.value}"):
                if candidate in sources and candidate != module:
                    named.add(candidate)
    return sorted(named)


def _targets(module: str, path: Path, tree: ast.Module, sources):
    """``(imported module, names, line, inside a function)`` of every import whose module is
    known; an unreadable import by name in a package face stands for each module it names."""
    for target, names, line, in_function in _imports(module, path, tree):
        if target is not None:
            yield target, names, line, in_function
        elif path.name == "__init__.py":
            for named in _named_modules(module, tree, sources):
                yield named, (), line, True


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
            if target is None:
                if path.name != "__init__.py":
                    problems.append(f"{at}: an import by a name the check cannot read")
                continue
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
                if upward and not face and not (
                        module == "fitting.cli" and target.startswith("fitting.cli.")):
                    problems.append(f"{at}: {module} imports {target}, which is not a layer "
                                    "before it")
            heavy = target.split(".")[0] in OPTIONAL_HEAVY
            if in_function and not heavy and not module.startswith(IN_FUNCTION_MODULES):
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


@pytest.mark.parametrize("snippet", [
    'import importlib\ndef f():\n    return importlib.import_module("fitting.fit")\n',
    'def f():\n    return __import__("fitting.fit")\n',
    'from importlib import import_module as load\ndef f():\n    return load("fitting.fit")\n',
    'import importlib\ndef f():\n    return importlib.import_module(".fit", package="fitting")\n',
    'import importlib\ndef f():\n    return importlib.import_module(__package__ + ".fit")\n',
    'import importlib.util\nSPEC = importlib.util.find_spec(f"{__package__}.fit")\n',
])
def test_the_check_sees_an_upward_import_by_name(snippet):
    sources = _sources()
    path, tree = sources["fitting.parameters"]
    extra = ast.parse(snippet)
    tree = ast.Module(body=[*extra.body, *tree.body], type_ignores=[])
    problems = layering_violations({**sources, "fitting.parameters": (path, tree)})
    assert any("fitting.parameters imports fitting.fit" in p for p in problems), problems


def test_the_check_refuses_an_import_by_a_name_it_cannot_read():
    sources = _sources()
    path, tree = sources["fitting.result"]
    extra = ast.parse("import importlib\ndef f(name):\n    return importlib.import_module(name)\n")
    tree = ast.Module(body=[*extra.body, *tree.body], type_ignores=[])
    problems = layering_violations({**sources, "fitting.result": (path, tree)})
    assert any("a name the check cannot read" in p for p in problems), problems


def import_graph(sources, package: str = "fitting") -> dict[str, set[str]]:
    """The modules of `package` each module of it imports (by any means, at module level or
    in a function; ``from a import b`` of a module ``a.b`` counts as importing ``a.b``).
    A package's ``__init__``, which Python runs before its modules, is drawn only where it is
    imported by name."""
    graph: dict[str, set[str]] = {m: set() for m in sources if m.split(".")[0] == package}
    for module in graph:
        path, tree = sources[module]
        for target, names, _, _ in _targets(module, path, tree, sources):
            for imported in [f"{target}.{n}" for n in names if f"{target}.{n}" in sources] or [
                    target]:
                if imported in graph and imported != module:
                    graph[module].add(imported)
    return graph


def circle(graph: dict[str, set[str]]) -> list[str] | None:
    """One circle of the graph as ``[a, b, ..., a]``, or ``None`` when it has none."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node):
        state[node] = 1
        path.append(node)
        for target in sorted(graph[node]):
            if state.get(target) == 1:
                return path[path.index(target):] + [target]
            if target not in state:
                found = visit(target)
                if found:
                    return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def test_the_import_drawing_of_fitting_has_no_circle():
    graph = import_graph(_sources())
    assert sum(len(t) for t in graph.values()) > len(graph)  # the drawing sees the imports
    found = circle(graph)
    assert found is None, " -> ".join(found)


def test_the_drawing_sees_a_circle_made_by_an_import_by_name():
    sources = _sources()
    path, tree = sources["fitting.result"]
    extra = ast.parse('import importlib\ndef f():\n    importlib.import_module("fitting.fit")\n')
    tree = ast.Module(body=[*extra.body, *tree.body], type_ignores=[])
    found = circle(import_graph({**sources, "fitting.result": (path, tree)}))
    assert found is not None and "fitting.result" in found and "fitting.fit" in found


if __name__ == "__main__":
    drawing = import_graph(_sources())
    for module in sorted(drawing):
        for target in sorted(drawing[module]):
            print(f"{module} -> {target}")
    found = circle(drawing)
    edges = sum(len(t) for t in drawing.values())
    print(f"{len(drawing)} modules, {edges} edges: "
          + ("no circle" if found is None else "circle: " + " -> ".join(found)))
