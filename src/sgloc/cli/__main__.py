"""`python -m sgloc.cli`: the same as the `sgloc` command."""

from sgloc.runtime import interrupts

interrupts.install_early()  # before the command line's imports

from sgloc.cli import main  # noqa: E402

main()
