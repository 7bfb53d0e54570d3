"""`python -m sgloc ...` runs the command line (as the `sgloc` script does)."""

from sgloc.cli import main

if __name__ == "__main__":
    main()  # the process's arguments; exits with the command's code
