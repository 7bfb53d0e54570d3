"""`python -m sgloc ...` runs the command line (as the `sgloc` script does)."""

import sys

from sgloc.cli import main

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
