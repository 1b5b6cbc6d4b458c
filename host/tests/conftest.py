import os
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def data_dir():
    return DATA


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p
