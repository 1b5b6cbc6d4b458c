"""`python3 -m bulgekit`: the `bulgekit` command."""
import sys

from .cli import main

sys.exit(main())
