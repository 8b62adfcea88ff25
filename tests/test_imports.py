"""No import cycle in src/fingerloc: every module imports, and the module import graph is acyclic.

The graph is built with ``ast`` from every ``import`` statement of the
package, those inside functions included (a lazy import is still a
dependency); only imports under ``if TYPE_CHECKING:`` are left out (they
never run). A package's ``__init__`` counts as the package.
"""

import ast
import importlib
from pathlib import Path

import networkx as nx
import pytest

import fingerloc

ROOT = Path(fingerloc.__file__).parent


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()

    def resolve(target: str) -> str | None:
        while target and target not in known:  # fingerloc.x.y.func -> fingerloc.x.y
            target = target.rpartition(".")[0]
        return target or None

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("fingerloc"):
                    out.add(resolve(a.name) or a.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.startswith("fingerloc"):
                for a in node.names:
                    full = resolve(f"{mod}.{a.name}")  # a submodule, or a name in mod
                    if full is not None:
                        out.add(full)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    out.discard(name)
    return {m for m in out if m in known}


def import_graph() -> nx.DiGraph:
    mods = _modules()
    g = nx.DiGraph()
    g.add_nodes_from(mods)
    for name, path in mods.items():
        for dep in _imports(name, path, set(mods)):
            if not name.startswith(dep + "."):  # a module importing its own package's __init__ is not a cycle
                g.add_edge(name, dep)
    return g


@pytest.mark.parametrize("name", sorted(_modules()))
def test_every_module_imports(name):
    importlib.import_module(name)


def test_no_import_cycle():
    g = import_graph()
    # a package __init__ re-exporting its submodules is not a cycle through them
    for pkg in [n for n in g if (ROOT.parent / n.replace(".", "/") / "__init__.py").exists()]:
        for child in list(g.successors(pkg)):
            if child.startswith(pkg + "."):
                g.remove_edge(pkg, child)
    cycles = sorted(sorted(c) for c in nx.simple_cycles(g) if len(c) > 1)
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles[:10])


def test_the_graph_sees_lazy_imports():
    """The checker itself: a function-level import is an edge, a TYPE_CHECKING one is not."""
    g = import_graph()
    assert g.has_edge("fingerloc.cli.track", "fingerloc.pipeline.mapping")  # imported inside a command function
    assert not g.has_edge("fingerloc.pipeline.presets", "fingerloc.observation")  # TYPE_CHECKING only


def test_test_modules_do_not_import_each_other():
    """Shared test helpers live in conftest.py or helper modules (``_*.py``), never in another test module."""
    import ast
    from pathlib import Path

    bad = []
    for path in sorted(Path(__file__).parent.glob("test_*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module:
                last = node.module.split(".")[-1]
                if last.startswith("test_"):
                    bad.append(f"{path.name}: from {node.module}")
    assert not bad, bad


#: The layers, lowest first: a module imports only modules of its own layer or lower ones.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("_estimator", "_lazy", "_lse", "_mog_kernels", "_numba_guard", "_seed_kernels", "_types", "_version", "angles", "atomic",
     "config", "errors", "metrics", "parallel", "sensors", "validation"),
    ("observation", "fingerprint", "keypoints"),
    ("_fingerprints", "io", "features", "sim", "mog", "align"),
    ("terms",),
    ("model", "retrieval"),
    ("map",),
    ("pipeline",),
    ("plot", "reporting"),
    ("experiments",),
    ("cli", "ros"),
)  # fmt: skip


def layer_of(module: str) -> int:
    """The layer of ``fingerloc.X...`` (its first component after the package)."""
    top = module.split(".")[1]
    for k, names in enumerate(LAYERS):
        if top in names:
            return k
    raise AssertionError(f"{module}: not in any layer (add {top!r} to LAYERS)")


def test_every_import_points_down_the_layers():
    g = import_graph()
    bad = [
        f"{a} ({layer_of(a)}) -> {b} ({layer_of(b)})"
        for a, b in g.edges()
        if a != "fingerloc" and b != "fingerloc" and layer_of(b) > layer_of(a)
    ]
    assert not bad, "imports up the layers: " + "; ".join(sorted(bad))


def test_the_layer_check_can_fail():
    assert layer_of("fingerloc.observation") < layer_of("fingerloc.features.keypoints") < layer_of("fingerloc.cli.track")
    with pytest.raises(AssertionError, match="not in any layer"):
        layer_of("fingerloc.nowhere")
