"""The shared API contract (``../shared/checks/api_contract.py``), run as a subprocess."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONTRACT = ROOT.parent / "shared" / "checks" / "api_contract.py"


@pytest.mark.skipif(not CONTRACT.exists(), reason=f"no API contract at {CONTRACT}")
def test_api_contract():
    proc = subprocess.run([sys.executable, str(CONTRACT)], cwd=ROOT, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "API contract: ok" in proc.stdout
