"""Helpers for the studio's tests and tools/studio_shots.py: a running studio, HTTP calls with
its token, a big G-code, and the CLI's own build of a placement file to compare with."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import urllib.error
import urllib.request
from contextlib import contextmanager
from pathlib import Path

from bulgekit.studio.server import Limits, Studio, serve

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
GCODE = EXAMPLES / "cylinder40x20.gcode"


def start(workdir, **limits):
    return serve(Studio(Path(workdir), Limits(**limits)), 0)


def call(run, path, data=None, *, method=None, headers=None, token=True, raw=False):
    """(status, parsed JSON or bytes) of one request to the running studio."""
    h = {"X-Studio-Token": run.studio.token} if token else {}
    if isinstance(data, (dict, list)):
        data = json.dumps(data).encode()
        h["Content-Type"] = "application/json"
    h.update(headers or {})
    req = urllib.request.Request(run.url.rstrip("/") + path, data=data, headers=h, method=method)
    try:
        with urllib.request.urlopen(req, timeout=300) as r:
            body, status = r.read(), r.status
    except urllib.error.HTTPError as e:
        body, status = e.read(), e.code
    if raw:
        return status, body
    try:
        return status, json.loads(body)
    except ValueError:
        return status, body


def wait_job(run, job, timeout=300):
    t0 = time.monotonic()
    while job["state"] == "running":
        assert time.monotonic() - t0 < timeout, f"job {job['kind']} still running after {timeout} s"
        time.sleep(0.1)
        _, job = call(run, f"/api/job/{job['id']}")
    return job


def open_gcode(run, path=GCODE, name=None):
    status, job = call(run, f"/api/gcode?name={name or Path(path).name}", Path(path).read_bytes())
    assert status == 200, job
    return wait_job(run, job)


@contextmanager
def fake_printer(**kw):
    """test_sender's fake Marlin on a pseudo-terminal: yields (port name, printer)."""
    import tty
    from test_sender import FakeMarlin
    master, slave = os.openpty()
    tty.setraw(slave)
    printer = FakeMarlin(master, **kw)
    printer.start()
    try:
        yield os.ttyname(slave), printer
    finally:
        printer.stop.set()
        printer.join(2)
        os.close(slave)
        os.close(master)


def cli_build(gcode, placement, outdir, name):
    """What `bulgekit build --placement` writes for the same placement file (a new process)."""
    cmd = [sys.executable, "-m", "bulgekit.cli", "build", str(gcode), "--placement", str(placement),
           "--fallback", "--preview-3d", "--name", name, "-o", str(outdir)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return sorted(p for p in Path(outdir).iterdir() if p.is_file())


def big_gcode(dst, target_bytes, src=GCODE):
    """The sample's layers stacked (Z shifted) until the file has target_bytes: a large, real
    sliced file with outer-wall comments on every layer."""
    lines = Path(src).read_text().splitlines(keepends=True)
    first = next(i for i, l in enumerate(lines) if l.startswith(";LAYER_CHANGE"))
    end = next(i for i in range(len(lines) - 1, 0, -1) if ";TYPE:" in lines[i])
    body = "".join(lines[first:end])
    top = max(float(z) for z in re.findall(r"^;Z:([\d.]+)", body, re.M))
    zrx = re.compile(r"(^G1 Z|^;Z:)([\d.]+)", re.M)
    with open(dst, "w") as f:
        f.write("".join(lines[:first]))
        k = size = 0
        while size < target_bytes:
            chunk = zrx.sub(lambda m, off=k * top: f"{m.group(1)}{float(m.group(2)) + off:.2f}", body)
            f.write(chunk)
            size += len(chunk)
            k += 1
        f.write("".join(lines[end:]))
    return Path(dst)
