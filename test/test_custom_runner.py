"""PlatformIO custom test runner for bktest (test/bktest.h).

bktest prints one line per case in Unity's form, which PlatformIO's Unity reader
already parses:  <file>:<line>:<name>:PASS|FAIL|IGNORE[: message]
and closes with "N passed, N failed" followed by Unity's "N Tests N Failures N
Ignored" line. This runner reuses that parser, echoes every other line (so
benchmark tables and simulator messages show), and needs no registry package.
"""
import click
from platformio.public import UnityTestRunner


class CustomTestRunner(UnityTestRunner):
    # bktest is compiled from test/ like any test source; nothing to fetch.
    EXTRA_LIB_DEPS = None

    def configure_build_env(self, env):
        return env

    def on_testing_line_output(self, line):
        parsed = self.parse_test_case(line.strip()) if line.strip() else None
        if not parsed and not self.options.verbose:
            click.echo(line, nl=False)
        super().on_testing_line_output(line)
