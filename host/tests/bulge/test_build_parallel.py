"""bulgekit.parallel.Forked, and `bulgekit build`'s preview drawn on a second core with it: the
job's value or error as if run here, in a child when a fork is safe, here when not (or when the
child dies), no child left behind; the preview's PNG the same bytes either way."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bulgekit import parallel

HOST = Path(__file__).resolve().parents[2]
GCODE = HOST / "tests" / "data" / "prusa_cyl.gcode"


def fresh(code: str, **env) -> str:
    """Run code in a fresh interpreter (one thread, so that a fork is allowed): its stdout."""
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(HOST), **env}, timeout=120)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_a_running_job_runs_in_a_child_and_its_value_comes_back():
    out = fresh("""
        import os
        from bulgekit import parallel
        assert parallel.can_fork(), "2+ cores, Linux, one thread: a fork is allowed"
        big = list(range(100000))          # the child sees this process's memory
        with parallel.Forked.running(lambda: (os.getpid(), sum(big), b"x" * 3_000_000)) as c:
            assert c.forked
            pid, total, blob = c.result()
        print(pid != os.getpid(), total, len(blob))
    """)
    assert out.split() == ["True", str(sum(range(100000))), "3000000"]


def test_a_waiting_child_warms_up_then_takes_a_pickled_job():
    out = fresh("""
        import os, sys
        from bulgekit import parallel
        c = parallel.Forked.waiting(lambda: __import__("fractions"))
        c.give(divmod, 17, 5)
        print(c.result(), c.forked)
        c.close()
    """)
    assert out.split() == ["(3,", "2)", "True"]


def test_the_jobs_error_is_raised_here_with_its_type_and_message():
    out = fresh("""
        from bulgekit import parallel
        from bulgekit.errors import InputError
        def bad():
            raise InputError("part.gcode: line 3: no such thing")
        c = parallel.Forked.running(bad)
        try:
            c.result()
        except InputError as e:
            print("raised:", e)
        c.close()
    """)
    assert out.strip() == "raised: part.gcode: line 3: no such thing"


def test_a_child_killed_without_a_result_leaves_the_job_to_this_process():
    out = fresh("""
        import os, signal
        from bulgekit import parallel
        me = os.getpid()
        def job():
            if os.getpid() != me:          # in the child: killed before it answers
                os.kill(os.getpid(), signal.SIGKILL)
            return "done here"
        c = parallel.Forked.running(job)
        print(c.forked, c.result())
    """)
    assert out.split() == ["True", "done", "here"]


def test_an_unpicklable_value_is_made_here_instead():
    out = fresh("""
        import os
        from bulgekit import parallel
        me = os.getpid()
        c = parallel.Forked.running(lambda: (lambda: os.getpid() == me))
        print(c.result()())
    """)
    assert out.strip() == "True"


def test_close_ends_a_child_still_working_and_leaves_no_process_or_pipe():
    out = fresh("""
        import os, time
        from bulgekit import parallel
        fds = sorted(os.listdir("/proc/self/fd"))
        c = parallel.Forked.running(lambda: time.sleep(60))
        w = parallel.Forked.waiting()      # and one never given a job
        pid = c._pid
        t = time.perf_counter()
        c.close()
        w.close()
        try:
            os.waitpid(pid, os.WNOHANG)
            gone = False
        except ChildProcessError:
            gone = True                    # reaped: no zombie left
        print(gone, time.perf_counter() - t < 5, sorted(os.listdir("/proc/self/fd")) == fds)
    """)
    assert out.split() == ["True", "True", "True"]


@pytest.mark.parametrize("why", ["env", "thread"])
def test_without_a_fork_the_job_runs_here_at_result(why):
    out = fresh(f"""
        import os, threading
        from bulgekit import parallel
        if {why!r} == "thread":            # another thread runs: forking is not safe
            ev = threading.Event()
            t = threading.Thread(target=ev.wait); t.start()
        assert not parallel.can_fork()
        ran = []
        c = parallel.Forked.running(lambda: ran.append(os.getpid()) or 7)
        before = list(ran)
        print(c.forked, before, c.result(), ran == [os.getpid()])
        if {why!r} == "thread":
            ev.set(); t.join()
    """, **({"BULGEKIT_FORK": "0"} if why == "env" else {}))
    assert out.split() == ["False", "[]", "7", "True"]


def test_a_job_is_given_once():
    c = parallel.Forked.waiting()
    try:
        c.give(abs, -1)
        with pytest.raises(RuntimeError, match="has its job already"):
            c.give(abs, -2)
        assert c.result() == 1
    finally:
        c.close()


def test_build_preview_drawn_beside_is_the_same_png(tmp_path):
    """The CLI's build with the preview drawn in a forked child and drawn in this process
    (BULGEKIT_FORK=0): every output file the same bytes."""
    outs = {}
    for fork in ("1", "0"):
        d = tmp_path / f"fork{fork}"
        fresh(f"""
            import sys
            from bulgekit.cli import main
            sys.argv = ["bulgekit", "build", {str(GCODE)!r}, "--text", "BK", "--text-size", "5",
                        "--at", "60,2", "-o", {str(d)!r}, "--fallback", "--quiet"]
            try:
                main()
            except SystemExit as e:
                assert not e.code, e.code
        """, BULGEKIT_FORK=fork)
        outs[fork] = {p.name: p.read_bytes() for p in sorted(d.iterdir())}
    assert "prusa_cyl.preview.png" in outs["1"]
    assert outs["1"].keys() == outs["0"].keys()
    for name in outs["1"]:
        assert outs["1"][name] == outs["0"][name], name


def test_build_that_fails_after_the_map_leaves_no_preview_and_no_child(tmp_path):
    """The map is placed (the child is given the drawing), then writing fails: no files, the
    child ended."""
    d = tmp_path / "out"
    d.mkdir()
    (d / "prusa_cyl.bulge.gcode").mkdir()          # annotate cannot write its file
    out = fresh(f"""
        import os, sys
        from bulgekit.cli import main
        sys.argv = ["bulgekit", "build", {str(GCODE)!r}, "--text", "BK", "--text-size", "5",
                    "--at", "60,2", "-o", {str(d)!r}, "--quiet"]
        try:
            main()
        except SystemExit as e:
            print("exit", e.code)
        try:
            os.waitpid(-1, os.WNOHANG)
            print("a child is left")
        except ChildProcessError:
            print("no child")
    """)
    assert "exit 1" in out and "no child" in out
    assert sorted(p.name for p in d.iterdir()) == ["prusa_cyl.bulge.gcode"]


def _annotate_runs(tmp_path, gcode, bmap, out, fork: str) -> str:
    """`bulgekit annotate` in a fresh interpreter: whether its reach check went to a child, its
    exit code and stderr's last line, the output's bytes (or 'none'), any .part and any child
    left."""
    return fresh(f"""
        import os, sys, hashlib
        from bulgekit.bulge import annotate
        from bulgekit.cli import main
        forked = []
        class Seen(annotate.Forked):
            def __init__(self, *a):
                super().__init__(*a)
                forked.append(self.forked)
        annotate.Forked = Seen
        sys.argv = ["bulgekit", "annotate", {str(gcode)!r}, {str(bmap)!r}, "-o", {str(out)!r}]
        sys.stderr = sys.stdout
        try:
            main()
        except SystemExit as e:
            print("exit", e.code)
        print("forked", forked)
        p = {str(out)!r}
        print("out", hashlib.sha256(open(p, "rb").read()).hexdigest() if os.path.isfile(p) else "none")
        print("part", any(n.endswith(".part") for n in os.listdir(os.path.dirname(p)))
              if os.path.isdir(os.path.dirname(p)) else False)
        try:
            os.waitpid(-1, os.WNOHANG)
            print("a child is left")
        except ChildProcessError:
            print("no child")
    """, BULGEKIT_FORK=fork)


def test_annotate_checks_reach_beside_the_markers_with_the_same_file_and_errors(tmp_path):
    """annotate's reach check runs in a forked child while the markers are made and written: the
    same file as in one process (BULGEKIT_FORK=0), and when a check fails, the same message, no
    file, no .part and no child. A map for another file (unreached points), a file annotated
    before (refused before anything else) and a folder that cannot be written (said after the
    checks, as before)."""
    from bulgekit.bulge.mapbuild import build
    from bulgekit.bulge.strokes import Stroke
    from bulgekit.bulge.wall import walls_from_gcode
    bmap = tmp_path / "cyl.bkm"
    bmap.write_bytes(build([Stroke(((10.0, 1.0), (10.0, 4.0)))], walls_from_gcode(GCODE)).map_bytes)
    other = tmp_path / "other.bkm"                  # points off the wall: no move reaches them
    other.write_bytes(mapformat_far())
    done = tmp_path / "done.gcode"
    cases = {"ok": (GCODE, bmap, tmp_path / "{}" / "a.gcode"),
             "unreached": (GCODE, other, tmp_path / "{}" / "b.gcode"),
             "annotated before": (done, bmap, tmp_path / "{}" / "c.gcode"),
             "no folder": (GCODE, bmap, tmp_path / "{}" / "missing" / "d.gcode")}
    seen = {}
    for fork in ("1", "0"):
        (tmp_path / fork).mkdir()
        if fork == "1":
            fresh(f"""
                import sys
                from bulgekit.cli import main
                sys.argv = ["bulgekit", "annotate", {str(GCODE)!r}, {str(bmap)!r}, "-o", {str(done)!r}]
                try:
                    main()
                except SystemExit as e:
                    assert not e.code, e.code
            """)
        for name, (g, m, out) in cases.items():
            seen[fork, name] = _annotate_runs(tmp_path, g, m, str(out).format(fork), fork)
    for name in cases:
        one, two = seen["1", name], seen["0", name]
        assert "forked [True]" in one and "forked [False]" in two, (name, one, two)
        same = lambda t: re.sub(r"\(\d+\.\d+ s\)", "", t.replace("/0/", "/1/"))  # noqa: E731 (not its time)
        assert same(one).replace("[True]", "") == same(two).replace("[False]", ""), name
        assert "part False" in one and "no child" in one
        if name == "ok":
            assert "out none" not in one and ("exit" not in one or "exit 0" in one)
        else:
            assert "out none" in one and "exit 1" in one, (name, one)
    assert "map points are not within" in seen["1", "unreached"]
    assert "bulge twice" in seen["1", "annotated before"]
    assert "missing/d.gcode: No such file" in seen["1", "no folder"]


def mapformat_far() -> bytes:
    from bulgekit.bulge import mapformat
    return mapformat.encode_map([(0.4, [(150.0, 150.0)]), (0.6, [(150.0, 150.0)])])
