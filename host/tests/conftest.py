import os
import sys
from pathlib import Path

# Test this checkout's package, not whichever bulgekit `pip install -e` last pointed at (a second
# clone's `make deps` re-points it): the host/ folder beside these tests comes first.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
# Tests import each other's fixtures across the folders (the studio's fake printer is
# printer/test_sender's): every test folder is on the path, after the package.
sys.path += [str(d) for d in sorted(Path(__file__).resolve().parent.iterdir())
             if d.is_dir() and any(d.glob("*.py")) and str(d) not in sys.path]

import pytest  # noqa: E402

DATA = Path(__file__).parent / "data"
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def data_dir():
    return DATA


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p
