"""`python3 -m bulgekit` and the `bulgekit` command (pyproject's [project.scripts])."""
import sys

from .outputs import ending


def run():
    """The command: SIGINT and SIGTERM end it as bulgekit.outputs.ending says from here on, also
    while its modules are imported."""
    with ending(exiting=True):
        from .cli import main

        return main()


if __name__ == "__main__":
    sys.exit(run())
