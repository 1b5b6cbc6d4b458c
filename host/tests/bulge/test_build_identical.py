"""`bulgekit build` writes the same bytes as before the one-reader change (issue 26): every output
(map, annotated G-code, stock file, stats) of every test file, in both stop modes, has the SHA-256
that the code at dacdbcd (before the change) wrote. The stock file's header has since gained a
line naming the printer model it was made for (fallback.PRINTER_HEADER): that one line is left
out of its hash, every other byte is compared. The statistics' hashes were made again when
their stop-and-start time came to be the printer model's (stopmodel.ramp_s, stats.timed_model)
instead of v/a at 1000 mm/s²: every G-code and map hash is still dacdbcd's. The hashes are in data/build_outputs.json;
to make them again from another checkout of the package:

    PYTHONPATH=/path/to/old/host python3 host/tests/bulge/test_build_identical.py --write
"""
from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
ROOT = HERE.parent.parent
REFERENCE = HERE / "data" / "build_outputs.json"

FILES = {"cura_cyl": HERE / "data" / "cura_cyl.gcode", "prusa_cyl": HERE / "data" / "prusa_cyl.gcode",
         "prusa_cyl_m83": HERE / "data" / "prusa_cyl_m83.gcode", "prusa_vase": HERE / "data" / "prusa_vase.gcode",
         "slic3r_cyl": HERE / "data" / "slic3r_cyl.gcode", "cylinder40x20": ROOT / "examples" / "cylinder40x20.gcode"}
NO_FEATURES = {"slic3r_cyl"}              # no feature comments: geometric mode only


def cases() -> list[tuple[str, str, list[str]]]:
    out = []
    for name in FILES:
        for stop in ("move", "g4"):
            geo = ["--geometric"] if name in NO_FEATURES else []
            out.append((f"{name}-{stop}{'-geometric' if geo else ''}", name, ["--stop", stop, *geo]))
    out.append(("prusa_cyl-move-geometric", "prusa_cyl", ["--stop", "move", "--geometric"]))
    return out


def build_hashes(case: str, name: str, args: list[str], tmp: Path) -> dict[str, str]:
    from click.testing import CliRunner

    from bulgekit.cli import main
    out = tmp / case
    r = CliRunner().invoke(main, ["build", str(FILES[name]), "--text", "HI", "--at", "5,3", "-o", str(out),
                                  "--fallback", "--no-preview", "--quiet", *args])
    assert r.exit_code == 0, r.output
    return {p.name: hashlib.sha256(_without_printer_line(p.read_bytes())).hexdigest()
            for p in sorted(out.iterdir())}


def _without_printer_line(data: bytes) -> bytes:
    from bulgekit.bulge.fallback import PRINTER_HEADER
    head = PRINTER_HEADER.encode()
    first = data.find(b"\n") + 1
    if data.startswith(b"; bulgekit fallback:") and data.startswith(head, first):
        return data[:first] + data[data.index(b"\n", first) + 1:]
    return data


def test_build_outputs_are_byte_identical(tmp_path):
    ref = json.loads(REFERENCE.read_text())
    assert sorted(ref) == sorted(c for c, _, _ in cases())
    for case, name, args in cases():
        got = build_hashes(case, name, args, tmp_path)
        assert got == ref[case], case


if __name__ == "__main__" and sys.argv[1:] == ["--write"]:
    with tempfile.TemporaryDirectory() as d:
        REFERENCE.write_text(json.dumps({c: build_hashes(c, n, a, Path(d)) for c, n, a in cases()},
                                        indent=1, sort_keys=True) + "\n")
    print(f"wrote {REFERENCE}")
