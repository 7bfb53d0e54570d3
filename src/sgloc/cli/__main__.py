"""`python -m sgloc.cli`: the same as the `sgloc` command."""

from sgloc.cli import main

main()
