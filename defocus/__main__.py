"""`python -m defocus`: the same as the `defocus` command."""

import sys

from defocus.cli import main

if __name__ == "__main__":
    sys.exit(main())
