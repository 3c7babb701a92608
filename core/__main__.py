"""``python -m amslam``: the ``amslam`` command line, for where the script is not on the PATH."""

import sys

from amslam.cli import main

if __name__ == "__main__":
    sys.exit(main())
