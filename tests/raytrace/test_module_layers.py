"""The modules of ``raytrace`` import one another without cycles, and the modules of numba
kernels import no module of the objects that drive them: read statically from the sources (every
import statement, at module level or inside a function)."""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "raytrace"

# modules that hold numba kernels (and their constants) and nothing that drives them
KERNELS = {"_sampling", "_surface", "_rows", "_gather", "_filter", "_edges", "_background", "_paths",
           "_cache_kernels", "_kernels", "_embree", "_lights"}
# what a kernel module may import besides the other kernel modules: numba's policy and the kernels
# of the environment and the BRDF
KERNEL_DEPENDENCIES = {"_jit", "environment", "brdf"}


def _modules() -> dict:
    """{dotted name within the package ("shade", "targets.cassini", "targets"): path}."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path, modules: dict) -> set:
    """The package's modules that ``name`` imports (``raytrace/__init__.py`` itself left out)."""
    parts = name.split(".") if name else []
    package = parts if path.name == "__init__.py" else parts[:-1]  # what ``from .`` means
    found = set()

    def add(dotted: str) -> None:
        # the longest prefix that is a module of the package
        parts = dotted.split(".")
        for k in range(len(parts), 0, -1):
            candidate = ".".join(parts[:k])
            if candidate in modules:
                found.add(candidate)
                return

    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("raytrace."):
                    add(alias.name[len("raytrace."):])
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: ``from . import a``, ``from .a import b``, ``from ..a import b``
                base = package[:len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            elif node.module == "raytrace" or (node.module or "").startswith("raytrace."):
                module = node.module[len("raytrace."):] if node.module != "raytrace" else ""
            else:
                continue
            for alias in node.names:  # the module ``module.alias`` where there is one, else ``module``
                add(".".join(filter(None, [module, alias.name])))
    found.discard(name)
    found.discard("")
    return found


def _graph() -> dict:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_the_reader_finds_the_imports():
    graph = _graph()
    assert {"_context", "_antialias", "_gather", "presets", "scene"} <= graph["shade"]
    assert {"_cache_kernels", "presets", "environment"} <= graph["cache"]
    assert "cache" in graph["scene"]  # imported inside a method
    assert "model" in graph["targets.cassini"]  # from ..model


def test_no_import_cycles():
    assert _cycles(_graph()) == []


def test_kernel_modules_import_no_module_of_objects():
    graph = _graph()
    assert KERNELS <= set(graph)
    for name in sorted(KERNELS):
        assert graph[name] <= KERNELS | KERNEL_DEPENDENCIES, (name, graph[name] - KERNELS - KERNEL_DEPENDENCIES)
    for name in KERNEL_DEPENDENCIES:
        assert graph[name] <= KERNELS | KERNEL_DEPENDENCIES, name
