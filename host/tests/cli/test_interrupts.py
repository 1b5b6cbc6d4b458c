"""Ctrl-C and SIGTERM in a command (issue 37): exit status 130 / 143 with one line on stderr,
no new file and no part left in the output folder, an earlier output of the same name as it
was, and no child left running. `build --fallback` (its stock file is written in a forked
child), `post-process` (the file replaced in place) and `litho`, each run as `python -m
bulgekit` and stopped at several moments of its run. The soak on a 100 MB file:
tools/interrupt_soak.py (docs/host.md, "Exit status")."""
from __future__ import annotations

import shutil
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "tools"))

from interrupt_soak import files as folder, stop_at, whole_run  # noqa: E402

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

# moments of the run, as shares of one whole run's time, counted from when the command's
# handlers are in place (before that Python itself is starting)
SHARES = (0.0, 0.15, 0.35, 0.55, 0.75, 0.9)


def check_stops(args, cwd, watched: Path, seconds: float, shares=SHARES, term_share=0.5, reset=None):
    """Each stop leaves `watched` (a folder) as the run before left it (the same files, none
    replaced, no part), with exit status 130 (143) and one line on stderr. A signal after the outputs went in place is too late: the run ends as
    usual, exit status 0, all its files new (then reset() puts the input back, if given)."""
    before = folder(watched)
    runs = [(s, signal.SIGINT, True) for s in shares] + [(shares[1], signal.SIGINT, False),
                                                        (term_share, signal.SIGTERM, False)]
    stopped = 0
    for share, sig, group in runs:
        code, err, left = stop_at(args, cwd, share * seconds, sig, group)
        assert not left, "a process of the command is left running"
        now = folder(watched)
        if code == 0:                                    # ended, or stopped too late
            # every output new (into a new folder: all of them there, none before)
            assert err == [] and before.keys() <= now.keys(), (share, sig, err)
            assert all(now[n] != before[n] for n in before if n != "mine.txt")
            before = now
            if reset is not None:
                reset()
                before = folder(watched)
            continue
        stopped += 1
        word = "interrupted" if sig == signal.SIGINT else "terminated"
        assert (code, err) == (128 + sig, [f"bulgekit: {word}"]), (share, sig)
        assert now == before, (share, sig)               # no new file, no part, none replaced
    assert stopped >= len(runs) - 2


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    """A generated file (bench_annotate.make_gcode, as tools/bench_host.py makes 100 MB)."""
    from bench_annotate import make_gcode
    p = tmp_path_factory.mktemp("big") / "big.gcode"
    make_gcode(p, 8)
    return p


def test_build_fallback_stopped_leaves_the_earlier_files(big, tmp_path):
    out = tmp_path / "out"
    seconds = whole_run(["build", big, "--text", "OLD", "--at", "5,3", "--fallback", "-o", out, "-q"],
                        tmp_path)
    assert {"big.stock.gcode", "big.bulge.gcode", "big.preview.png"} <= set(folder(out))
    (out / "mine.txt").write_text("the user's own file\n")
    check_stops(["build", big, "--text", "HELLO", "--at", "5,3", "--fallback", "-o", out, "-q"],
                tmp_path, out, seconds)


def test_build_stopped_into_a_new_folder_leaves_no_folder(big, tmp_path):
    args = ["build", big, "--text", "HELLO", "--at", "5,3", "--fallback", "-o", tmp_path / "new" / "out"]
    seconds = whole_run(args, tmp_path)
    shutil.rmtree(tmp_path / "new")
    # (a run the signal reached too late, on a loaded machine, made the folder: taken away again)
    check_stops(args, tmp_path, tmp_path, seconds, shares=(0.3, 0.6, 0.9),
                reset=lambda: shutil.rmtree(tmp_path / "new"))
    assert not (tmp_path / "new").exists()


def test_post_process_stopped_leaves_the_slicers_file(big, tmp_path):
    g = tmp_path / "slicer" / "part.gcode"
    g.parent.mkdir()
    shutil.copy(big, g)
    pl = tmp_path / "p.toml"
    pl.write_text('[[text]]\ntext = "HI"\nat = [5, 3]\nsize = 5\n\n[bulges]\nfallback = true\n')
    args = ["post-process", "--placement", pl, "--keep", tmp_path / "slicer" / "kept", g]
    seconds = whole_run(args, tmp_path)
    again = lambda: shutil.copy(big, g)                 # noqa: E731 (the slicer's file again)
    again()
    check_stops(args, tmp_path, g.parent, seconds, shares=(0.1, 0.4, 0.7, 0.9), reset=again)


def test_litho_stopped_leaves_the_earlier_files(tmp_path):
    a = np.full((40, 200), 255, np.uint8)
    a[:, :100] = 0
    pic = tmp_path / "p.png"
    Image.fromarray(a).save(pic)
    out = tmp_path / "o"
    args = ["litho", pic, "-o", out, "--width", 100, "--height", 20, "--foot", 0, "-q"]
    seconds = whole_run(args, tmp_path)
    Image.fromarray(a[:, ::-1]).save(pic)               # the next run's files differ
    check_stops(args, tmp_path, out, seconds, shares=(0.1, 0.4, 0.7, 0.9))


@pytest.mark.parametrize("fallback", [[], ["--fallback"]])
def test_build_that_fails_half_way_leaves_the_earlier_files(data_dir, tmp_path, monkeypatch, fallback):
    """An error after the map, annotated G-code, stock file and stats are written (the preview
    fails): exit status 1, and the folder as the run before left it."""
    from click.testing import CliRunner
    from bulgekit.bulge import preview
    from bulgekit.cli import main
    from bulgekit.errors import BulgekitError
    out = tmp_path / "out"
    args = ["build", str(data_dir / "prusa_cyl.gcode"), "--at", "10,2", "--text-size", "4", "-o", str(out),
            *fallback]
    assert CliRunner().invoke(main, [*args, "--text", "OLD"]).exit_code == 0
    before = folder(out)

    def broken(*a, **kw):
        raise BulgekitError("the preview cannot be drawn")
    monkeypatch.setattr(preview, "build_unrolled", broken)
    r = CliRunner().invoke(main, [*args, "--text", "NEW"])
    assert r.exit_code == 1 and "the preview cannot be drawn" in r.output
    assert folder(out) == before
