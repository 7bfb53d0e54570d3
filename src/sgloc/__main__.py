"""`python -m sgloc ...` runs the command line (as the `sgloc` script does)."""

from sgloc.runtime import interrupts

if __name__ == "__main__":
    interrupts.install_early()  # before the command line's imports

from sgloc.cli import main  # noqa: E402

if __name__ == "__main__":
    main()  # the process's arguments; exits with the command's code
