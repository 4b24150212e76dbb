"""Dependencies point one way, ``sitl`` -> ``companion`` -> ``rota``, and no modules
import each other in a circle: read from every module's own import statements
(function-level ones too), not from what a run happens to load."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: what each package may not import
FORBIDDEN = {"rota": ("companion", "sitl"), "companion": ("sitl",)}


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, top-level package) of every import in ``path``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module.split(".")[0]))
    return out


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_no_package_imports_the_ones_above_it(package):
    bad = [f"{p.relative_to(ROOT)}:{line} imports {name}"
           for p in sorted((ROOT / package).rglob("*.py"))
           for line, name in imports(p) if name in FORBIDDEN[package]]
    assert not bad, "\n".join(bad)


def test_the_check_sees_a_forbidden_import(tmp_path):
    """(it can fail: a function-level import is found as well as a top-level one)"""
    f = tmp_path / "m.py"
    f.write_text("import os\n\ndef g():\n    from sitl.world import get_world\n")
    assert (4, "sitl") in imports(f)


def _module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _runtime_imports(path: Path, name: str, is_package: bool) -> list[str]:
    """Every module ``path`` imports at run time, at any level (absolute names);
    imports under ``if TYPE_CHECKING:`` are for the type checker only and left out."""
    tree = ast.parse(path.read_text(), str(path))
    skip = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
            and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING"
            for n in ast.walk(node)}
    out = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                here = name.split(".") if is_package else name.split(".")[:-1]
                here = here[:len(here) - node.level + 1]
                base = ".".join(here + ([node.module] if node.module else []))
            out += [base] + [f"{base}.{a.name}" for a in node.names]
    return out


def import_cycles(root: Path, packages: tuple[str, ...]) -> list[list[str]]:
    """The sets of modules of ``packages`` under ``root`` that import each other in a
    circle (strongly connected, more than one module)."""
    files = {_module_name(p, root): p for pkg in packages for p in (root / pkg).rglob("*.py")}

    def owner(target: str) -> str | None:
        while target and target not in files:
            target = target.rpartition(".")[0]
        return target or None

    graph = {m: {o for t in _runtime_imports(p, m, p.name == "__init__.py")
                 if (o := owner(t)) and o != m} for m, p in files.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = stack[stack.index(v):]
            del stack[stack.index(v):]
            if len(part) > 1:
                cycles.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def test_no_module_imports_itself_through_others():
    """No import circles in the three packages, counting imports made inside
    functions too (a circle hidden in a function is still one)."""
    assert import_cycles(ROOT, ("rota", "companion", "sitl")) == []


def test_the_cycle_check_sees_a_circle_hidden_in_a_function(tmp_path):
    pkg = tmp_path / "p"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from p.b import g\n")
    (pkg / "b.py").write_text("def g():\n    from p import a\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\n"
                              "if TYPE_CHECKING:\n    from p.a import g\n")
    assert import_cycles(tmp_path, ("p",)) == [["p.a", "p.b"]]  # (c's is type-only)


#: The longest a source file of the packages may be: a file a reader takes in whole
MAX_LINES = 600


def test_no_source_file_is_longer_than_a_reader_takes_in_whole():
    long = [f"{p.relative_to(ROOT)}: {n} lines" for pkg in ("rota", "companion", "sitl")
            for p in sorted((ROOT / pkg).rglob("*.py"))
            if (n := len(p.read_text().splitlines())) > MAX_LINES]
    assert not long, "\n".join(long)


def _root(node: ast.AST) -> str | None:
    while isinstance(node, ast.Attribute):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def callbacks_wired_after(source: str) -> list[int]:
    """Lines that hand a part a callback after it was built: ``self.part.x = <a lambda
    or one of self's methods>``."""
    return [node.lineno for node in ast.walk(ast.parse(source)) if isinstance(node, ast.Assign)
            for t in node.targets
            if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Attribute)
            and _root(t) == "self"
            and (isinstance(node.value, ast.Lambda) or _root(node.value) == "self")]


def test_the_service_is_wired_through_constructors():
    """The composition root (companion/service.py) gives each part its callbacks when
    it builds it, never by assigning them afterwards (it can fail: see the sample)."""
    sample = "class S:\n    def f(self):\n        self.stream.on_halt = self._halted\n" \
             "        self.a.b = lambda: 1\n        self.commander.state = State.STOPPING\n"
    assert callbacks_wired_after(sample) == [3, 4]
    assert callbacks_wired_after((ROOT / "companion" / "service.py").read_text()) == []


#: What a decode worker must not load (each costs memory in every worker process, and the
#: first is what filterpy brings: scipy.stats): the estimator, the recorder, MAVLink and
#: the network stacks belong to the service's own process
NOT_IN_A_DECODE_WORKER = ("filterpy", "scipy.stats", "mcap", "foxglove", "mavsdk", "zenoh",
                          "numba")


def test_a_decode_worker_loads_what_it_decodes_with_and_no_more():
    """Measured in a fresh interpreter: the modules a decode worker has, those the fork
    server imports for every worker (companion.worker.PRELOAD) and the messages it decodes
    into. (Neither MAVSDK nor Zenoh may be among them: their threads would be
    forked with the server's state.)"""
    import subprocess
    import sys

    from companion.worker import PRELOAD

    assert "companion.network.decoder" in PRELOAD
    code = (f"import sys, companion.messages, {', '.join(PRELOAD)}\n"
            f"bad = [m for m in {NOT_IN_A_DECODE_WORKER!r} if m in sys.modules]\n"
            "print(' '.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=True)
    assert out.stdout.strip() == "", f"a decode worker loads {out.stdout.strip()}"
