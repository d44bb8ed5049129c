"""What a SITL run leaves in its output folder (a mixin of :class:`mpcasv.io.sitl.Sitl`;
the world, rows and options live there): ``acoustics.toml`` (the world's acoustic channel,
for the deploy's configuration) at the start and, at the end, ``run/`` as ``mpcasv
simulate`` writes a run (:func:`mpcasv.sim.record.write_run`)."""

from __future__ import annotations

import dataclasses

import numpy as np


class RunOutput:
    """The SITL's output files (module docstring)."""

    def write_acoustics(self) -> dict:
        """``<out>/acoustics.toml``: the world's acoustic channel (the scenario's, drawn for
        the seed) as the deploy configuration's ``[acoustics]`` table, which an MPC plans
        its fixes with; ``mpcasv simulate`` of the same scenario and seed plans with it.
        Returns the table (for the ready information)."""
        import tomli_w

        head = ("# the acoustic channel of this SITL's world (scenario "
                f"{self.sc.name!r}, seed {self.opt.seed}): paste into the deploy "
                "configuration\n# so that an MPC plans with it, as mpcasv simulate of the same "
                "scenario and seed does\n")  # fmt: skip
        channel = dataclasses.asdict(self.sc.acoustics)
        (self.opt.out / "acoustics.toml").write_text(head + tomli_w.dumps({"acoustics": channel}))
        return channel

    def finish(self, wall_s: float, overruns: int) -> dict:
        """Close the sockets and write the run folder; return the run info. A world that
        never completed a period writes none: the info then says why (``no_run``: held at
        t = 0 by ``--hold``, no Reference having come, or stopped within the first period)."""
        import pandas as pd

        from mpcasv.experiments.metrics import compute_metrics
        from mpcasv.sim.record import write_run
        from mpcasv.sim.scenario import scenario_with
        from mpcasv.sim.simulator import RunResult

        self.close_sockets()
        w = self.world
        info = {"ts_offset": self.ts_offset, "periods": len(self.rows), "speedup":
                self.opt.speedup, "overruns": overruns, "counts": self.counts,
                "sitl_wall_s": wall_s,
                "auv_states": self.opt.auv_states, "usbl_delay": self.opt.usbl_delay,
                **({"lockstep": True} if self.opt.lockstep else {})}  # fmt: skip
        if not self.rows:
            info["no_run"] = ("the world stood at t = 0 (--hold): no Reference came" if self.held
                              else "stopped before the world's first period ended")
        self.event("finished", **info)
        self.jsonl.close()
        self.lsf.close()
        if self.rows:
            sc = scenario_with(self.sc, duration=len(self.rows) * self.Tc)
            res = RunResult(sc, "sitl", self.opt.seed, pd.DataFrame(self.rows),
                            np.zeros(len(self.rows)), w.fix_times, w.reliable_times, 0, None, [],
                            w.energy_J, w.min_range, w.min_slant, wall_s, self.domain)  # fmt: skip
            info["metrics"] = write_run(res, self.opt.out / "run", compute_metrics(res),
                                        plots=self.opt.plots, extra={
                                            "sitl": info,
                                            "realisation": self.realisation.as_dict()})  # fmt: skip
        return info
