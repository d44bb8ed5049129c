"""CasADi NMPC for the ASV: donut / anti-collision constraints and a fix-age cost (docs/mpc.md).

- :mod:`mpcasv.mpc.params`: the presets' dataclasses;
- :mod:`mpcasv.mpc.problem`: the optimal control problem (built once, stage-interleaved);
- :mod:`mpcasv.mpc.derivatives`, :mod:`mpcasv.mpc.codegen`: stage-wise derivatives, compiled
  and cached on disk;
- :mod:`mpcasv.mpc.solvers` (fatrop / IPOPT), :mod:`mpcasv.mpc.qp` (linearised, OSQP);
- :mod:`mpcasv.mpc.controller`: ``mpc-single`` / ``mpc-multi`` with the hybrid safety fallback;
- :mod:`mpcasv.mpc.reference`, :mod:`mpcasv.mpc.bench`: the straightforward Opti + IPOPT
  formulation and ``mpcasv bench mpc``.
"""
