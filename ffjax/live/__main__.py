"""python -m ffjax.live --checkpoint RUN (--camera N | --video FILE | --images DIR) [--out DIR] ...: see tool.py."""

import sys

from ffjax import cli
from ffjax.live.tool import main

if __name__ == "__main__":
    sys.exit(cli.run(main))
