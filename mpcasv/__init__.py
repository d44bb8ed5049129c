"""mpcasv: an ASV supporting AUVs with acoustic fixes.

The published hybrid ("donut") controllers beside a CasADi MPC, on one shared Fossen 3-DOF
vessel model, with tuning tools and an IMC (LSTS DUNE) deployment layer. See README.md and
docs/ for the workflows.
"""

__version__ = "0.1.0"


def run() -> int:
    """The ``mpcasv`` console script: :func:`mpcasv.cli.main`, with a Ctrl-C while the
    program is still loading (its imports, before ``main`` can catch it) ending it as one
    during a command does: one line on stderr, exit 130, no traceback."""
    import sys

    try:
        from mpcasv.cli import main
    except KeyboardInterrupt:
        print("mpcasv: interrupted", file=sys.stderr)
        return 130
    return main()
