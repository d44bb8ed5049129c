import sys

from mpcasv.cli import main

sys.exit(main())
