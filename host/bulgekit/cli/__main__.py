"""`python3 -m bulgekit.cli`: the `bulgekit` command (as bulgekit/__main__.py runs it)."""
import sys

from ..outputs import ending
from . import main

with ending(exiting=True):
    sys.exit(main())
