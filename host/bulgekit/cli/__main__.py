"""`python3 -m bulgekit.cli`: the `bulgekit` command."""
import sys

from . import main

sys.exit(main())
