"""`bulgekit litho` writes the same bytes as before the package was split by stage (issue 37,
item 3): every output (litho and stock G-code, STL, transmission PNG, JSON) of every case below
has the SHA-256 that the code at 262b08f (main, before the split) wrote. The hashes are in
data/litho_outputs.json; to make them again from another checkout of the package:

    PYTHONPATH=/path/to/old/host python3 host/tests/litho/test_litho_identical.py --write

The picture is written into the run's folder and named by a relative path, so the JSON's
"image" is the same in every run. The narrow plates' transmission pictures (40 and 30 mm) were
hashed again when their panel labels came to wrap instead of running into the next panel
(backlit._wrapped); every other byte is still 262b08f's.

Item 5 (the picture's aspect, the arc, the likeness) then added options and figures on purpose;
`_without_additions` leaves out of both sides exactly those: the G-code header's lines of the
options added since (ADDED_OPTIONS), and in the JSON those options, the new blocks
(ADDED_BLOCKS) and the look's figures that were replaced (REPLACED_LOOK). Every other byte is
compared: the moves, the STL, the PNG, the rest of the JSON.
"""
from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
ROOT = HERE.parent.parent
REFERENCE = HERE / "data" / "litho_outputs.json"

ADDED_OPTIONS = ("angle", "stretch")
ADDED_BLOCKS = ("stands", "picture")
REPLACED_LOOK = ("mean_abs_dL", "ssim_L", "correlation", "picture_vs_print")
SMALL = ["--quiet", "--no-purge"]
CASES = {
    "astronaut-planar-e": ("astronaut", ["--width", "40", *SMALL]),
    "astronaut-planar-w": ("astronaut", ["--width", "40", "--words", "w", "--frame", "1", *SMALL]),
    "astronaut-cylinder-e": ("astronaut", ["--shape", "cylinder", "--diameter", "20", *SMALL]),
    "astronaut-cylinder-w": ("astronaut", ["--shape", "cylinder", "--diameter", "20", "--words", "w",
                                           "--accel", "1000", *SMALL]),
    "drawing-planar": ("drawing", ["--width", "30", "--curve", "linear", "--foot", "0", *SMALL]),
    "calibration": (None, ["--calibration", *SMALL]),
}


def _picture(which: str | None, d: Path) -> list[str]:
    if which is None:
        return []
    if which == "drawing":
        (d / "drawing.png").write_bytes((ROOT / "examples" / "litho" / "drawing.png").read_bytes())
        return ["drawing.png"]
    from PIL import Image
    from skimage import data
    Image.fromarray(data.astronaut()).resize((96, 96), Image.Resampling.LANCZOS).save(d / "astronaut.png")
    return ["astronaut.png"]


def litho_hashes(case: str, tmp: Path) -> dict[str, str]:
    from click.testing import CliRunner

    from bulgekit.cli import main
    which, args = CASES[case]
    d = tmp / case
    d.mkdir(parents=True)
    here = os.getcwd()
    os.chdir(d)
    try:
        r = CliRunner().invoke(main, ["litho", *_picture(which, d), "-o", "out", *args])
    finally:
        os.chdir(here)
    assert r.exit_code == 0, r.output
    return {p.name: hashlib.sha256(_without_additions(p)).hexdigest() for p in sorted((d / "out").iterdir())}


def _without_additions(p: Path) -> bytes:
    data = p.read_bytes()
    if p.name.endswith(".gcode"):
        drop = tuple(f"; {k} = ".encode() for k in ADDED_OPTIONS)
        return b"".join(line for line in data.splitlines(keepends=True) if not line.startswith(drop))
    if p.name.endswith(".json"):
        d = json.loads(data)
        for k in ADDED_BLOCKS:
            d.pop(k, None)
        for k in ADDED_OPTIONS:
            d["options"].pop(k, None)
        for k in REPLACED_LOOK:
            d["look"].pop(k, None)
        return (json.dumps(d, indent=2) + "\n").encode()
    return data


def test_litho_outputs_are_byte_identical(tmp_path):
    ref = json.loads(REFERENCE.read_text())
    assert sorted(ref) == sorted(CASES)
    for case in CASES:
        assert litho_hashes(case, tmp_path) == ref[case], case


if __name__ == "__main__" and sys.argv[1:] == ["--write"]:
    with tempfile.TemporaryDirectory() as d:
        REFERENCE.write_text(json.dumps({c: litho_hashes(c, Path(d)) for c in CASES},
                                        indent=1, sort_keys=True) + "\n")
    print(f"wrote {REFERENCE}")
