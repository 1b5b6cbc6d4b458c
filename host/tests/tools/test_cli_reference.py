"""docs/reference/cli.md is every command's --help as the code prints it (tools/cli_reference.py)."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def test_the_cli_reference_is_what_the_commands_print():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "cli_reference.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr + "\n(run: python3 tools/cli_reference.py)"
