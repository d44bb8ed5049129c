import sys

from mpcasv import run

sys.exit(run())
