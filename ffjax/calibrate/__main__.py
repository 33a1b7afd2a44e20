"""python -m ffjax.calibrate --checkpoint RUN --data CSV --out DIR [--layers last|regressor]: see tool.py."""

import sys

from ffjax.calibrate.tool import main

if __name__ == "__main__":
    from ffjax import cli

    sys.exit(cli.run(main))
