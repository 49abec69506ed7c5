"""The package's layering rules, checked on the source tree (no Taichi needed).

* No file imports another module's private (underscore) name, and none (the
  tests included: they use the public names a user has) reads a private
  attribute that a module of the package defines and its own does not.
* Data flows one way: a subpackage imports only from the layers below it
  (``LAYERS``), and nothing in the numerical core imports the application layer.
* Modules stay short (``MAX_MODULE_LINES``): a longer one holds more than one job.
"""
import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "taichi_hh"
TREES = ("taichi_hh", "scenes", "benchmarks", "tests")

#: each subpackage and the subpackages it may import from (top-level modules
#: ``errors``, ``checks``, ``runtime`` are below everything)
LAYERS = {
    "sph": set(),
    "geometry": set(),
    "linalg": set(),                   # generic: knows nothing of particles
    "poisson": {"sph", "linalg"},      # the SPH Poisson rows, the multilevel preconditioner
    "hhd": {"sph", "geometry", "linalg", "poisson"},
    "flow": {"sph", "geometry", "linalg", "poisson"},
    "validation": {"sph", "geometry", "linalg", "poisson", "hhd", "flow"},
    "app": {"sph", "geometry", "linalg", "poisson", "hhd", "flow", "validation"},
}


def _sources():
    for tree in TREES:
        for path in sorted((ROOT / tree).rglob("*.py")):
            if "__pycache__" not in path.parts:
                yield path


def _module_name(path: pathlib.Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _resolve(path: pathlib.Path, node: ast.ImportFrom) -> str:
    """Absolute module name of an ``from X import ...`` statement."""
    if node.level == 0:
        return node.module or ""
    package = _module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    base = package[: len(package) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _own_private_names(tree: ast.AST) -> set:
    """Private names a module defines: functions, classes, module globals,
    attributes assigned anywhere in it (``self._x = ...``) and names it spells
    out as strings (``__slots__``, ``setattr``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and node.value.isidentifier():
            names.add(node.value)     # __slots__ entries, setattr(self, "_x", ...)
    return {n for n in names if _is_private(n)}


def _private_names_of_the_package() -> set:
    names = set()
    for path in sorted(PACKAGE.rglob("*.py")):
        if "__pycache__" not in path.parts:
            names |= _own_private_names(ast.parse(path.read_text()))
    return names


def _violations():
    found = []
    package_private = _private_names_of_the_package()
    for path in _sources():
        tree = ast.parse(path.read_text(), filename=str(path))
        rel = path.relative_to(ROOT)
        own = _own_private_names(tree)
        foreign_modules = set()        # local names bound to modules outside the package
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                module = _resolve(path, node)
                ours = module == "taichi_hh" or module.startswith("taichi_hh.")
                for alias in node.names:
                    if ours and _is_private(alias.name):
                        found.append(f"{rel}:{node.lineno} imports {module}.{alias.name}")
                    if not ours:
                        foreign_modules.add(alias.asname or alias.name)
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if _is_private(alias.name.split(".")[-1]) and alias.name.startswith("taichi_hh"):
                        found.append(f"{rel}:{node.lineno} imports {alias.name}")
                    if not alias.name.startswith("taichi_hh"):
                        foreign_modules.add((alias.asname or alias.name).split(".")[0])
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and _is_private(node.attr)):
                continue
            base = node.value
            if isinstance(base, ast.Name) and base.id in ("self", "cls"):
                continue
            if isinstance(base, ast.Name) and base.id in foreign_modules:
                continue          # another library's business (checked where it matters)
            if node.attr in own or node.attr not in package_private:
                continue          # its own, or another library's (argparse's _actions)
            found.append(f"{rel}:{node.lineno} reads {ast.unparse(node)}")
    return found


def test_no_private_names_cross_module_boundaries():
    assert _violations() == []


def _subpackage(module: str):
    parts = module.split(".")
    return parts[1] if len(parts) > 2 and parts[0] == "taichi_hh" else None


def _imported_modules(path: pathlib.Path):
    """(line, module) of every import in a file: ``from X import a`` gives X and
    X.a (a may be a module)."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            module = _resolve(path, node)
            yield node.lineno, module
            for a in node.names:
                yield node.lineno, f"{module}.{a.name}"
        elif isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name


def test_every_subpackage_has_a_layer():
    """A new subpackage is placed in LAYERS, so the order is checked for it too."""
    subpackages = {p.parent.name for p in PACKAGE.glob("*/__init__.py")}
    assert subpackages == set(LAYERS)


def test_linalg_knows_nothing_of_particles():
    """linalg/ is generic: it imports nothing from sph/ or poisson/ (issue 30:
    the SPH Poisson rows and the multilevel preconditioner, built on SPH pairs,
    are the poisson/ layer above it), not even inside a function."""
    bad = [f"{path.relative_to(ROOT)}:{line} imports {module}"
           for path in sorted((PACKAGE / "linalg").rglob("*.py"))
           for line, module in _imported_modules(path)
           if _subpackage(module) in ("sph", "poisson")]
    assert bad == []


def test_subpackages_import_only_layers_below():
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        me = _subpackage(_module_name(path)) if path.parent != PACKAGE else None
        if me is None:
            continue
        for line, target in _imported_modules(path):
            other = _subpackage(target)
            if other and other != me and other in LAYERS and other not in LAYERS[me]:
                bad.append(f"{path.relative_to(ROOT)}:{line} ({me}) imports {target}")
    assert sorted(set(bad)) == []


@pytest.mark.parametrize("name", ["errors", "runtime"])
def test_bottom_modules_import_no_subpackage(name):
    tree = ast.parse((PACKAGE / f"{name}.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            assert node.module in (None, "errors", "checks", "runtime", "kernel_transform"), \
                ast.unparse(node)


#: the most lines a module of a checked subpackage may have: past it a file
#: holds more than one job (issue 30: krylov.py's 1.4k lines held kernels, CSR
#: matrices, stopping tests and two drivers)
MAX_MODULE_LINES = 700
#: subpackages whose modules are held to MAX_MODULE_LINES: all of them
SHORT_MODULE_TREES = tuple(LAYERS)
#: modules still over the limit, each with the split that will bring it under:
#: an entry is removed when its split lands (the test fails on a stale entry)
PENDING_SPLITS = {
}


def test_modules_stay_short():
    long = {}
    for tree in SHORT_MODULE_TREES:
        for path in sorted((PACKAGE / tree).rglob("*.py")):
            lines = len(path.read_text().splitlines())
            if lines > MAX_MODULE_LINES:
                long[path.relative_to(ROOT).as_posix()] = lines
    unexplained = {name: lines for name, lines in long.items() if name not in PENDING_SPLITS}
    assert unexplained == {}, f"modules over {MAX_MODULE_LINES} lines: split them by job"
    stale = [name for name in PENDING_SPLITS
             if name.startswith(tuple(f"taichi_hh/{t}/" for t in SHORT_MODULE_TREES))
             and name not in long]
    assert stale == [], "split (or moved): remove from PENDING_SPLITS"
