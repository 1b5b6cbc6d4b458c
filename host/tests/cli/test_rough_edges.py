"""Rough edges a new user hit (issue 12), each with its fix: a binary file given as G-code, the
first unsupported character named, a failed build leaving nothing behind, stats warnings on
stderr with a non-zero status, and range errors naming their option."""
from __future__ import annotations

import pytest
from click.testing import CliRunner

from bulgekit.bulge import mapformat
from bulgekit.cli import main
from bulgekit.errors import InputError
from bulgekit.bulge.strokes import text_strokes


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_binary_file_as_gcode(tmp_path):
    binary = tmp_path / "ls"
    binary.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(256)) * 40)
    out = tmp_path / "out"
    r = run("build", binary, "--text", "HI", "-o", out)
    assert r.exit_code != 0
    assert f"{binary}: not a text G-code file (binary data: a NUL byte at byte 7)" in r.output
    assert len(r.output) < 300                     # one line, not the file's bytes
    assert not out.exists()
    m = tmp_path / "x.bkm"
    m.write_bytes(mapformat.encode_map([(0.6, [(100.0, 80.0)])], layer_height_mm=0.3))
    for cmd in ("annotate", "fallback"):
        r = run(cmd, binary, m, "-o", tmp_path / "a.gcode")
        assert r.exit_code == 1 and "not a text G-code file (binary data: a NUL byte at byte 7)" in r.output
        assert not (tmp_path / "a.gcode").exists()


def test_first_unsupported_character_is_named():
    # ü and ß are drawn (u + diaeresis; ß by bulgekit, see test_fonts.py); ✓ is the first missing one
    with pytest.raises(InputError, match=r"character '✓' \(position 7\)"):
        text_strokes("Grüße ✓ ☃", 6)


@pytest.mark.parametrize("ch, base, marks", [("é", "e", 1), ("ü", "u", 2), ("ñ", "n", 1),
                                               ("Å", "A", 1), ("ç", "c", 1), ("í", "i", 1)])
def test_latin1_accented_letters_are_their_letter_and_an_accent(ch, base, marks):
    got, plain = text_strokes(ch, 6), text_strokes(base, 6)
    # the letter's own strokes (the i without its dot), then the accent's
    keep = plain[1:] if base == "i" else plain
    assert [s.points for s in got[:len(keep)]] == [s.points for s in keep]
    accent = got[len(keep):]
    assert len(accent) == marks
    top = max(v for s in keep for _, v in s.points)
    pts = [p for s in accent for p in s.points]
    if ch == "ç":                                   # the cedilla hangs below the baseline
        assert min(v for _, v in pts) < -0.5
    else:
        assert min(v for _, v in pts) > top         # above the letter, inside its width
        lo, hi = min(u for s in keep for u, _ in s.points), max(u for s in keep for u, _ in s.points)
        assert all(lo - 0.5 <= u <= hi + 0.5 for u, _ in pts)


def test_failed_build_leaves_no_folder(tmp_path, data_dir):
    out = tmp_path / "never"
    # text far above the 10 mm part: no layer there, the build fails after reading the walls
    r = run("build", data_dir / "prusa_cyl.gcode", "--text", "HI", "--at", "0,50", "-o", out)
    assert r.exit_code != 0
    assert not out.exists()


def test_stats_warnings_go_to_stderr_and_fail(tmp_path, data_dir):
    m = tmp_path / "far.bkm"
    m.write_bytes(mapformat.encode_map([(0.6, [(150.0, 150.0)])], layer_height_mm=0.3))
    r = CliRunner().invoke(main, ["stats", str(m), "--gcode", str(data_dir / "prusa_cyl.gcode")])
    assert r.exit_code == 1
    assert "WARNING: 1 points are not within" in r.stderr
    assert "WARNING" not in r.stdout and "stops when printed: 0 of 1 points" in r.stdout


@pytest.mark.parametrize("opt, value, name", [("--dwell", "-100", "'--dwell'"), ("--extra", "9", "'--extra'"),
                                              ("--tolerance", "0.001", "'--tolerance'")])
def test_range_errors_name_the_option(tmp_path, data_dir, opt, value, name):
    m = tmp_path / "a.bkm"
    m.write_bytes(mapformat.encode_map([(0.6, [(100.0, 80.0)])], layer_height_mm=0.3))
    r = run("stats", m, opt, value)
    assert r.exit_code == 2
    assert f"Invalid value for {name}" in r.output


def test_tests_import_this_checkout():
    """make test in a second clone tests that clone's code, whatever `pip install -e` points at."""
    from pathlib import Path
    import bulgekit
    assert Path(bulgekit.__file__).resolve().parents[1] == Path(__file__).resolve().parents[2]


def test_at_past_the_wall_is_said_once(tmp_path, data_dir):
    # the 40 mm cylinder's wall is about 125 mm round: text at u 200 wraps to u ~74
    r = run("build", data_dir / "prusa_cyl.gcode", "--text", "HI", "--at", "200,3", "--size", "3",
            "-o", tmp_path / "o", "--no-preview")
    assert r.exit_code == 0, r.output
    notes = [l for l in r.output.splitlines() if "past the outer wall" in l]
    assert len(notes) == 1 and "the wall is a loop" in notes[0]
    r = run("build", data_dir / "prusa_cyl.gcode", "--text", "HI", "--at", "10,3", "--size", "3",
            "-o", tmp_path / "p", "--no-preview")
    assert r.exit_code == 0 and "past the outer wall" not in r.output


def test_build_has_the_text_options_of_strokes(tmp_path, data_dir):
    """--font, --letter-spacing and --scale as in `strokes`: each changes the map."""
    strokes = data_dir.parent / "data_inputs" / "strokes.json"

    def map_bytes(*extra, at="10,3"):
        out = tmp_path / ("o" + "_".join(map(str, extra)).replace("-", "").replace(".", "").replace("/", ""))
        r = run("build", data_dir / "prusa_cyl.gcode", "--at", at, "-o", out, "--no-preview", *extra)
        assert r.exit_code == 0, r.output
        return (out / "prusa_cyl.bkm").read_bytes()
    text = ("--text", "HI", "--size", "3")
    base = map_bytes(*text)
    assert map_bytes(*text, "--letter-spacing", "2") != base
    assert map_bytes(*text, "--font", "futuram") != base
    assert map_bytes("-s", strokes, "--scale", "0.5", at="10,1") != map_bytes("-s", strokes, "--scale", "0.4", at="10,1")
    r = run("build", data_dir / "prusa_cyl.gcode", "--text", "HI", "--font", "nosuch", "-o", tmp_path / "x")
    assert r.exit_code != 0 and "unknown font 'nosuch'" in r.output


def test_progress_is_shown_only_when_switched_on(tmp_path, data_dir):
    """The passes over the G-code report on stderr when a terminal asks for it (the CLI switches
    it on for a tty without --quiet); a slicer, a pipe or CliRunner gets none."""
    import io
    from bulgekit.bulge import api
    from bulgekit import progress
    buf = io.StringIO()
    progress.enable(buf)
    try:
        api.build(data_dir / "prusa_cyl.gcode", text_strokes("HI", 3, u0=10, v0=3), tmp_path / "o",
                  write_fallback=True)
    finally:
        progress.disable()
    shown = buf.getvalue()
    for label in ("reading the walls", "annotating"):
        assert f"{label}: done in" in shown
    # the stock file and the statistics are made in a forked child where one can be forked
    # (bulgekit.parallel), which shows no lines of its own: then the parent shows one for both
    assert ("stock fallback and statistics: done in" in shown
            or "stock fallback: done in" in shown and "statistics: done in" in shown), shown
    r = CliRunner().invoke(main, ["build", str(data_dir / "prusa_cyl.gcode"), "--text", "HI", "--at", "10,3",
                                  "--size", "3", "-o", str(tmp_path / "p"), "--no-preview"])
    assert r.exit_code == 0 and "done in" in r.stdout and r.stderr == ""
    r = CliRunner().invoke(main, ["build", str(data_dir / "prusa_cyl.gcode"), "--text", "HI", "--at", "10,3",
                                  "--size", "3", "-o", str(tmp_path / "q"), "--no-preview", "--quiet"])
    assert r.exit_code == 0 and r.stderr == ""


def test_progress_ticks_on_a_long_file(tmp_path):
    """parse_lines ticks every 16,384 lines: a pass over 50,000 lines redraws its line."""
    import io
    from bulgekit import progress
    from bulgekit.gcode import parse_lines
    buf = io.StringIO()
    progress.enable(buf)
    progress._state = None
    try:
        with progress.phase("test pass", total_lines=50000):
            for i, _ in enumerate(parse_lines(f"G1 X{i % 100} Y1 E0.1\n" for i in range(50000))):
                if i % 16384 == 16383:
                    progress._state[3] = 0.0          # let the next tick draw at once
    finally:
        progress.disable()
    assert "test pass:  32 % (16,384 of 50,000 lines)" in buf.getvalue()
    assert "test pass: done in" in buf.getvalue()


def test_progress_shows_a_rate_only_after_a_second(monkeypatch):
    """A pass that jumps through records it holds drew '43,955,334 lines/s' at its first tick: the
    rate and the time left now come once the pass has run RATE_AFTER_S."""
    import io
    from bulgekit import progress
    clock = [100.0]
    monkeypatch.setattr(progress.time, "perf_counter", lambda: clock[0])
    buf = io.StringIO()
    progress.enable(buf)
    try:
        with progress.phase("pass", total_lines=1000):
            clock[0] += 0.001
            progress.tick(900)                      # the first tick: percent only, no rate
            assert "pass:  90 % (900 of 1,000 lines)" in buf.getvalue() and "lines/s" not in buf.getvalue()
            clock[0] += 0.3
            progress.tick(950)                      # 0.3 s: still no rate
            assert "pass:  95 % (950 of 1,000 lines)" in buf.getvalue() and "lines/s" not in buf.getvalue()
            clock[0] += 1.699
            progress.tick(1000)                     # 2 s: 500 lines/s
            assert "1,000 of 1,000 lines), 500 lines/s, 0 s left" in buf.getvalue()
    finally:
        progress.disable()


def test_svg_text_and_fill_are_said_in_builds_words(tmp_path):
    """An SVG <text> is refused with the build's own option named (not `strokes --text`), skipped
    with a warning under build --skip-unsupported; a filled shape is drawn as its outline and
    that is said, once, with the first shape's line."""
    from click.testing import CliRunner
    from bulgekit.cli import main
    from pathlib import Path
    gcode = Path(__file__).parents[3] / "examples" / "cylinder40x20.gcode"
    svg = tmp_path / "d.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="20mm" height="10mm" viewBox="0 0 20 10">\n'
                   '<rect x="1" y="1" width="8" height="8" style="fill:#000"/>\n'
                   '<circle cx="14" cy="5" r="3" fill="red"/>\n'
                   '<text x="1" y="9">A</text>\n'
                   '<path d="M 10 5 L 19 5" style="fill:none;stroke:#000"/>\n</svg>\n')
    args = ["build", str(gcode), "-s", str(svg), "--at", "3,5", "-o", str(tmp_path / "o"), "--no-preview", "-q"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 1 and "--text, or a [[text]] table" in r.stderr and "strokes --text" not in r.stderr
    r = CliRunner().invoke(main, args + ["--skip-unsupported"])
    assert r.exit_code == 0, r.stderr
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("WARNING:")]
    assert len(warn) == 2, r.stderr
    assert "<text>" in warn[0] and "skipped" in warn[0]
    assert "2 filled shape(s) drawn as their outlines only (the first: " in warn[1] and ":2 <rect>" in warn[1]
