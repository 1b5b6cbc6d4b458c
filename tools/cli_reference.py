#!/usr/bin/env python3
"""Write docs/reference/cli.md: every `bulgekit` command's --help, as the command prints it.

    python3 tools/cli_reference.py            # rewrite the page
    python3 tools/cli_reference.py --check    # exit 1 if the page is not what the code prints

host/tests/tools/test_cli_reference.py runs --check, so the page cannot fall behind the code.
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "host"))
PAGE = ROOT / "docs" / "reference" / "cli.md"


def commands(group, prefix=()):
    """(path of names, command) of every command below group, in the order `--help` lists them."""
    import click
    ctx = click.Context(group, info_name="bulgekit")
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        if cmd is None or cmd.hidden:
            continue
        yield prefix + (name,), cmd
        if isinstance(cmd, click.Group):
            yield from commands(cmd, prefix + (name,))


def page() -> str:
    from click.testing import CliRunner

    from bulgekit.cli import main
    run = CliRunner()
    out = ["# The `bulgekit` command", "",
           "Every command's `--help`, as it prints it (made by `tools/cli_reference.py`; a test keeps it",
           "in step with the code). The guide for makers is [docs/guide](../guide/README.md).", ""]
    top = run.invoke(main, ["--help"], terminal_width=100, prog_name="bulgekit")
    out += ["## bulgekit", "", "```", top.output.rstrip(), "```", ""]
    for path, _ in commands(main):
        r = run.invoke(main, [*path, "--help"], terminal_width=100, prog_name="bulgekit")
        if r.exit_code != 0:
            raise SystemExit(f"cli_reference: bulgekit {' '.join(path)} --help failed: {r.output}")
        out += [f"## bulgekit {' '.join(path)}", "", "```", r.output.rstrip(), "```", ""]
    return "\n".join(out)


def main() -> int:
    text = page()
    if sys.argv[1:] == ["--check"]:
        if not PAGE.is_file() or PAGE.read_text(encoding="utf-8") != text:
            print(f"cli_reference: {PAGE.relative_to(ROOT)} is not what the commands print: "
                  "run python3 tools/cli_reference.py", file=sys.stderr)
            return 1
        return 0
    PAGE.parent.mkdir(parents=True, exist_ok=True)
    PAGE.write_text(text, encoding="utf-8")
    print(f"wrote {PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
