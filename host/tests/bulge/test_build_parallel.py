"""bulgekit.parallel.Forked, and `bulgekit build`'s preview drawn on a second core with it: the
job's value or error as if run here, in a child when a fork is safe, here when not (or when the
child dies), no child left behind; the preview's PNG the same bytes either way."""
from __future__ import annotations

import os
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
