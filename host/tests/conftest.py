import os
import sys
from pathlib import Path

# Test this checkout's package, not whichever bulgekit `pip install -e` last pointed at (a second
# clone's `make deps` re-points it): the host/ folder beside these tests comes first.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

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
