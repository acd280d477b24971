"""The house rules of the layout, read from the source (no imports run): the three packages never
import each other (only ``cli.py`` joins them), no import cycle between any two modules (lazy
imports inside functions count), the modules of numba kernels import no module of the objects
that drive them, and no module grows past what one reader holds."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROOMS = ("orbit", "raytrace", "degrade")
MAX_LINES = {"cli.py": 1000, "raytrace": 900}
"""Largest file [lines]: ``cli.py`` (the face and the composition root), any module of ``raytrace``."""
KERNELS = {f"raytrace.{m}" for m in ("_sampling", "_surface", "_rows", "_gather", "_filter", "_edges", "_background",
                                     "_paths", "_cache_kernels", "_kernels", "_embree", "_lights", "_lens",
                                     "_texture", "_earth")}
"""The modules of ``raytrace`` that hold numba kernels (and their constants) and nothing that drives them."""
KERNEL_DEPENDENCIES = {"raytrace._jit", "raytrace.environment", "raytrace.brdf", "raytrace._diskcache"}
"""What a kernel module may import besides the other kernel modules: numba's policy, the
kernels of the environment and the BRDF, and the persistent cache of the BRDF's table."""


def _modules() -> dict:
    """Dotted module name → path, for cli and every module of the three packages."""
    out = {"cli": ROOT / "cli.py"}
    for room in ROOMS:
        for path in sorted((ROOT / room).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


def _imports(name: str, path: Path, modules: dict) -> set:
    """The project modules ``name`` imports anywhere in its source (module level or inside functions)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            # `from pkg import mod` imports the module pkg.mod; `from mod import name` the module mod
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        found.update(t for t in targets if t in modules and t != name)
    return found


def _graph() -> dict:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def test_the_three_packages_never_import_each_other_nor_the_command_line():
    bad = [(a, b) for a, deps in _graph().items() for b in deps
           if a != "cli" and (b == "cli" or b.split(".")[0] != a.split(".")[0])]
    assert not bad, bad


def _cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return cycles


def test_no_import_cycle_between_modules():
    assert _cycles(_graph()) == []
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_kernel_modules_import_no_module_of_objects():
    graph = _graph()
    assert KERNELS <= set(graph)
    allowed = KERNELS | KERNEL_DEPENDENCIES
    for name in sorted(KERNELS | KERNEL_DEPENDENCIES):
        assert graph[name] <= allowed, (name, graph[name] - allowed)


def test_the_checker_sees_imports_and_cycles():
    """The graph is not empty by mistake: edges the code is known to have are found."""
    graph = _graph()
    assert "orbit.plan" in graph["cli"] and "raytrace.dataset.run" in graph["cli"]
    assert "raytrace.dataset.pool" in graph["raytrace.dataset.run"]  # `from . import folder, jit, pool`
    assert "degrade.chain" in graph["degrade.presets"]  # a lazy import inside a function
    assert "raytrace.cache" in graph["raytrace.scene"]  # inside a method
    assert "raytrace.model" in graph["raytrace.targets.cassini"]  # from ..model
    assert {"raytrace._context", "raytrace._antialias", "raytrace._gather", "raytrace.presets",
            "raytrace.scene"} <= graph["raytrace.shade"]
    assert {"raytrace._cache_kernels", "raytrace.presets", "raytrace.environment"} <= graph["raytrace.cache"]


def test_no_module_is_larger_than_a_reader_holds():
    sizes = {"cli.py": len((ROOT / "cli.py").read_text().splitlines())}
    sizes.update({str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in (ROOT / "raytrace").rglob("*.py")})
    big = {f: n for f, n in sizes.items() if n > MAX_LINES["cli.py" if f == "cli.py" else "raytrace"]}
    assert not big, big
