"""Dependencies point one way, ``sitl`` -> ``companion`` -> ``rota`` (issue 28): read
from every module's own import statements (function-level ones too), not from what a
run happens to load."""

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
