#!/usr/bin/env python3
"""Runs every bulgekit test and prints one closing line with the totals.

  1. C++ suites (test/test_*/) on the host (PlatformIO env `native`),
  2. the same suites on a simulated ATmega2560 (env `avr_sim`, run in bksim),
  3. the same suites on a Cortex-M3 and a Cortex-M4F in QEMU (envs `cm3_qemu`,
     `cm4f_qemu`, run by tools/sim/bkqemu),
  4. extra checks registered in tools/checks.d/ (e.g. a short fuzz run),
  5. the host package's pytest suite (host/tests).

Usage: tools/run_tests.py [--only native|avr_sim|cm3_qemu|cm4f_qemu|checks|pytest]... [-f FILTER]
Exit status is non-zero if anything failed or errored, or if no test ran.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


TARGETS = ("native", "avr_sim", "cm3_qemu", "cm4f_qemu")  # PlatformIO envs: the C++ suites
PARTS = TARGETS + ("checks", "pytest")


def run(cmd, **kw):
    print("$ " + " ".join(cmd), flush=True)
    return subprocess.run(cmd, cwd=ROOT, **kw).returncode


def pio_env(env, filters, tmp):
    report = os.path.join(tmp, f"{env}.json")
    cmd = ["pio", "test", "-e", env, "--json-output-path", report]
    for f in filters:
        cmd += ["-f", f]
    rc = run(cmd)
    passed = failed = 0
    if os.path.exists(report):
        with open(report, encoding="utf8") as fp:
            data = json.load(fp)
        for suite in data.get("test_suites", []):
            for case in suite.get("test_cases", []):
                status = case.get("status")
                if status == "PASSED":
                    passed += 1
                elif status in ("FAILED", "ERRORED"):
                    failed += 1
            if not suite.get("test_cases") and suite.get("status") != "SKIPPED":
                failed += 1  # a suite that produced no cases (crash, build error)
    elif rc != 0:
        failed += 1
    if rc != 0 and failed == 0:
        failed = 1  # PlatformIO failed without a case to blame
    return passed, failed


def checks(tmp):
    passed = failed = 0
    d = os.path.join(ROOT, "tools", "checks.d")
    if not os.path.isdir(d):
        return 0, 0
    for name in sorted(os.listdir(d)):
        path = os.path.join(d, name)
        if not os.access(path, os.X_OK):
            continue
        rc = run([path])
        print(f"check {name}: {'PASS' if rc == 0 else 'FAIL'}", flush=True)
        if rc == 0:
            passed += 1
        else:
            failed += 1
    return passed, failed


def pytest(tmp):
    tests = os.path.join(ROOT, "host", "tests")
    if not os.path.isdir(tests):
        return 0, 0
    xml = os.path.join(tmp, "pytest.xml")
    rc = run([sys.executable, "-m", "pytest", "-q", tests, f"--junitxml={xml}"])
    passed = failed = 0
    if os.path.exists(xml):
        root = ET.parse(xml).getroot()
        suites = [root] if root.tag == "testsuite" else list(root)
        for s in suites:
            total = int(s.get("tests", 0))
            bad = int(s.get("failures", 0)) + int(s.get("errors", 0))
            skipped = int(s.get("skipped", 0))
            passed += total - bad - skipped
            failed += bad
    if rc not in (0,) and failed == 0:
        failed = 1
    return passed, failed


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", action="append", choices=list(PARTS))
    ap.add_argument("-f", "--filter", action="append", default=[], help="PlatformIO test filter, e.g. 'test_planner'")
    args = ap.parse_args()
    parts = args.only or list(PARTS)
    totals = {}
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        for part in parts:
            start = time.time()
            if part in TARGETS:
                totals[part] = pio_env(part, args.filter, tmp)
            elif part == "checks":
                totals[part] = checks(tmp)
            else:
                totals[part] = pytest(tmp)
            p, f = totals[part]
            print(f"== {part}: {p} passed, {f} failed ({time.time() - start:.1f} s)", flush=True)
    passed = sum(p for p, _ in totals.values())
    failed = sum(f for _, f in totals.values())
    print(f"== all parts in {time.time() - t0:.1f} s: " + ", ".join(f"{k} {p}/{p + f}" for k, (p, f) in totals.items()))
    print(f"total: {passed} passed, {failed} failed")
    return 1 if failed or passed == 0 else 0


if __name__ == "__main__":
    sys.exit(main())
