"""Running the CLIs as a user does, and checking their one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys

PY = sys.executable


TOOLS = {"rota": "rota.cli", "rota-companion": "companion.cli", "rota-sim": "sitl.cli",
         "rota-sitl": "sitl.experiment_cli", "rota-gs": "companion.gs.cli"}


def run(tool: str, *args: str, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", TOOLS[tool], *args], capture_output=True, text=True,
                          timeout=timeout, **kw)


def one_line_error(r: subprocess.CompletedProcess, code: int, *words: str) -> None:
    assert r.returncode == code, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    for w in words:
        assert w in lines[0], lines[0]


def write_config(tmp_path, **sections) -> str:
    lines = []
    for section, values in sections.items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in values.items()]
    path = tmp_path / "c.toml"
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def console_command(tool: str) -> list[str]:
    """The command as its console script runs it (pyproject's [project.scripts]),
    after a line "started" on stderr: the interpreter's own start-up (its site
    imports, 0.1-0.2 s here) comes before any code of the project can act, and a
    Ctrl-C in it gives Python's own traceback: wait for that line first."""
    module, func = {"rota": ("companion.entry", "rota"),
                    "rota-companion": ("companion.entry", "companion"),
                    "rota-gs": ("companion.entry", "gs"),
                    "rota-sim": ("sitl.entry", "sim"),
                    "rota-sitl": ("sitl.entry", "sitl")}[tool]
    return [PY, "-c", "import sys; print('started', file=sys.stderr, flush=True); "
            f"from {module} import {func}; sys.argv[0] = {tool!r}; "
            f"sys.exit({func}())"]
