"""The package's compiled parts: the G-code move scanner (bulgekit/gcode/_scan.c), the estimator's
planner passes (gcode/_plan.c) and the reach check's planning (bulge/_reach.c). They are optional:
without a C compiler (or without Python's headers) the package installs all the same and its
numpy/Python code does their work, to the same results, slower (`bulgekit --version` says which
scanner is in use).

Building the package also puts the studio's front-end libraries in place (web/build.py: three.js
from npm, pinned by web/package-lock.json), so that a wheel carries them. They are optional too:
without npm the package is built without them, and `bulgekit studio` says what is missing."""
import subprocess
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_py import build_py


class BuildPy(build_py):
    def run(self):
        web = Path(__file__).resolve().parent / "web" / "build.py"
        if web.is_file() and subprocess.run([sys.executable, str(web)]).returncode != 0:
            print("setup.py: building without the studio's three.js (web/build.py failed, see above); "
                  "everything but `bulgekit studio` works", file=sys.stderr)
        super().run()


setup(cmdclass={"build_py": BuildPy},
      ext_modules=[Extension("bulgekit.gcode._scan", ["bulgekit/gcode/_scan.c"], optional=True,
                             extra_compile_args=["-O2"]),
                   # the estimator's planner passes; no fused multiply-add: the same bits as numpy
                   Extension("bulgekit.gcode._plan", ["bulgekit/gcode/_plan.c"], optional=True,
                             extra_compile_args=["-O2", "-ffp-contract=off"]),
                   # the reach check's planning (bulge/fallback.py): float32 as the Python planner
                   Extension("bulgekit.bulge._reach", ["bulgekit/bulge/_reach.c"], optional=True,
                             extra_compile_args=["-O2", "-ffp-contract=off"])])
