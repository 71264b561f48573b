"""The shared API contract (``<repo>/../shared/checks/api_contract.py``), run as a subprocess.

Where the shared directory is: ``$FACTIRL_SHARED`` if set, else ``../shared`` beside the
repository (the layout of CI's clone), else ``/work/shared`` (the development machine, for
runs from a git worktree). Without it the test is skipped locally and FAILS in CI (``CI`` set
to ``true``), so a CI run can never pass without checking the contract.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LOCAL_FALLBACK = Path("/work/shared")


def shared_dir(environ=None, root=None):
    """The shared directory to use, or None (``$FACTIRL_SHARED`` is used as given)."""
    environ = os.environ if environ is None else environ
    root = ROOT if root is None else root
    if environ.get("FACTIRL_SHARED"):
        return Path(environ["FACTIRL_SHARED"])
    for candidate in (root.parent / "shared", LOCAL_FALLBACK):
        if candidate.is_dir():
            return candidate
    return None


def in_ci(environ=None):
    return (os.environ if environ is None else environ).get("CI", "").strip().lower() in ("true", "1", "yes")


def _contract():
    shared = shared_dir()
    contract = shared / "checks" / "api_contract.py" if shared is not None else None
    if contract is not None and contract.is_file():
        return contract
    reason = (f"no API contract at {contract}" if contract is not None else
              f"no shared directory: set FACTIRL_SHARED, or clone it to {ROOT.parent / 'shared'}")
    if in_ci() or os.environ.get("FACTIRL_SHARED"):
        pytest.fail(reason)
    pytest.skip(reason)


def test_api_contract():
    contract = _contract()
    proc = subprocess.run([sys.executable, str(contract)], cwd=ROOT, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "API contract: ok" in proc.stdout


def test_shared_dir_resolution(tmp_path):
    repo = tmp_path / "clone"
    repo.mkdir()
    (tmp_path / "shared").mkdir()
    assert shared_dir({}, repo) == tmp_path / "shared"  # CI's layout: ../shared beside the clone
    assert shared_dir({"FACTIRL_SHARED": "/x/y"}, repo) == Path("/x/y")  # the variable wins
    assert in_ci({"CI": "true"}) and in_ci({"CI": "1"}) and not in_ci({}) and not in_ci({"CI": "false"})


def test_missing_contract_fails_in_ci(tmp_path, monkeypatch):
    monkeypatch.setenv("FACTIRL_SHARED", str(tmp_path / "absent"))
    with pytest.raises(pytest.fail.Exception, match="no API contract"):
        _contract()
    monkeypatch.delenv("FACTIRL_SHARED")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path / "clone")
    monkeypatch.setattr(sys.modules[__name__], "LOCAL_FALLBACK", tmp_path / "nowhere")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="no shared directory"):
        _contract()
    monkeypatch.setenv("CI", "false")
    with pytest.raises(pytest.skip.Exception):
        _contract()
