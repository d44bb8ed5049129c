"""mpcasv: an ASV supporting AUVs with acoustic fixes.

The published hybrid ("donut") controllers beside a CasADi MPC, on one shared Fossen 3-DOF
vessel model, with tuning tools and an IMC (LSTS DUNE) deployment layer. See README.md and
docs/ for the workflows.
"""

__version__ = "0.1.0"
