"""The package's one compiled part: the G-code move scanner (bulgekit/_scan.c). It is optional:
without a C compiler the package installs and reads G-code with the pure-Python parser
(slower; `python3 -m bulgekit.movescan` says which one is in use)."""
from setuptools import Extension, setup

setup(ext_modules=[Extension("bulgekit._scan", ["bulgekit/_scan.c"], optional=True,
                             extra_compile_args=["-O2"])])
