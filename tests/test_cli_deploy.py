"""The shipped systemd unit: ``systemd-analyze verify`` passes once the
executable exists where the deployment guide installs it, and
``systemd-analyze security`` rates it 3.0 or lower."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parents[1] / "configs" / "rota-companion.service"
pytestmark = pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                                reason="systemd-analyze not installed (Debian: systemd)")


def _installed_unit(tmp_path: Path) -> Path:
    """The unit as the guide installs it, ExecStart pointing at this checkout's
    rota-companion (the guide's /opt/rota-companion/.venv is not here)."""
    exe = Path(sys.executable).parent / "rota-companion"
    assert exe.exists()
    text = UNIT.read_text()
    assert "/opt/rota-companion/.venv/bin/rota-companion run" in text
    out = tmp_path / "rota-companion.service"
    out.write_text(text.replace("/opt/rota-companion/.venv/bin/rota-companion", str(exe)))
    return out


def test_unit_verifies(tmp_path):
    r = subprocess.run(["systemd-analyze", "verify", str(_installed_unit(tmp_path))],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "rota-companion" not in r.stderr, r.stderr


def test_unit_security_exposure_at_most_3(tmp_path):
    r = subprocess.run(["systemd-analyze", "security", "--offline=yes",
                        str(_installed_unit(tmp_path))], capture_output=True, text=True,
                       timeout=60)
    m = re.search(r"Overall exposure level for \S+: ([\d.]+)", r.stdout)
    assert m, r.stdout + r.stderr
    assert float(m.group(1)) <= 3.0, r.stdout


def test_unit_keeps_serial_access_and_a_fixed_user():
    text = UNIT.read_text()
    assert "DynamicUser=yes" not in text
    assert re.search(r"^SupplementaryGroups=dialout$", text, re.M)
    assert re.search(r"^DeviceAllow=char-ttyAMA rw$", text, re.M)
    assert re.search(r"^StateDirectory=rota-companion$", text, re.M)
