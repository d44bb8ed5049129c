"""A runtime speed cap on the MPC's plan (issue 16 item 1; docs/mpc.md, "Variables and
dynamics"): the speed the boat can actually make, learned in the field (``mpcasv deploy``'s
speed watch: DUNE's speed loop on the Otter never reaches the model's top speed,
docs/deploy.md "Achieved speed"). A mixin of :class:`~mpcasv.mpc.controller.MPCController`.

A speed loop that cannot exceed ``u_cap`` is modelled by capping the planned thrust at the
steady thrust for that speed, ``T_cap = thrust_for_speed(u_cap)`` (still water, straight
ahead), from stage 1 on (stage 0 is the measured state): bounds applied per solve
(:meth:`~mpcasv.mpc.problem.OCP.bounds`; a thrust above the cap comes down at the plan's
rate limit, :meth:`~mpcasv.mpc.problem.OCP.thrust_caps`), so nothing is recompiled. Where the
controller assumes a transit speed it uses the capped one:

- the terminal cost's time to go (``inv_U_go`` in the parameters, eq. M7) and the target
  choice's projected fix ages (eq. M9), the visiting order's transit model (eq. O1) and the
  variance objective's meeting points and transit cost: ``min(U_go, u_cap)``;
- the guesses the solver starts from (exploration towards the target, the hybrid command's
  rollout: ``min(speed, u_cap)``; the escape manoeuvre: ``T_cap`` instead of full thrust),
  which would otherwise start outside the capped bounds;
- the TRANSIT command's speed: at most ``u_cap``.

No cap (the default, None) leaves every one of these exactly as before.
"""

from __future__ import annotations

import math

import numpy as np

from mpcasv.mpc.layout import WEIGHT_NAMES

_INV_U_GO = WEIGHT_NAMES.index("inv_U_go")


class SpeedCap:
    """The plan's speed cap (mixin; state in the controller: ``u_cap`` as requested, the
    applied ``u_plan`` and ``T_cap``)."""

    #: the cap requested (m/s; :meth:`set_speed_cap`); None: none
    u_cap: float | None = None
    #: the cap the current step plans with (m/s): ``u_cap`` as of the step's start
    u_plan: float | None = None
    #: the steady thrust holding ``u_plan`` (N, at most ``T_max``); None: no cap
    T_cap: float | None = None

    def set_speed_cap(self, u_cap: float | None) -> None:
        """Cap the surge speed the plan may use at ``u_cap`` (m/s, through the water), from
        the next step on (the deploy sets it from its event loop while a step may be solving
        in another thread: a step plans with one cap throughout); None removes the cap. The
        controller's state (warm start, fix ages, target) is kept; the cap survives
        :meth:`reset`.

        The planned thrust is bounded by the steady thrust for ``u_cap`` (the vessel model's
        :meth:`~mpcasv.models.vessel.VesselModel.thrust_for_speed`), the transit speed the
        target choice and the terminal cost assume becomes ``min(U_go, u_cap)`` and the
        commanded TRANSIT speed is at most ``u_cap`` (module docstring). A cap at or above
        the vessel's top speed leaves the thrust bound at ``T_max``.

        Raises
        ------
        ValueError
            ``u_cap`` is not a positive finite number.
        """
        if u_cap is not None:
            u_cap = float(u_cap)
            if not (math.isfinite(u_cap) and u_cap > 0.0):
                raise ValueError(f"{self.name}: speed cap must be a positive finite speed "
                                 f"(m/s), got {u_cap!r}")  # fmt: skip
        self.u_cap = u_cap

    def _take_speed_cap(self, rebuilt: bool = False) -> None:
        """At a step's start (and after the problem is rebuilt, ``rebuilt``): plan with the
        cap requested, ``T_cap`` on this problem's vessel."""
        u = self.u_cap
        if u == self.u_plan and not rebuilt:
            return
        ocp = self.ocp
        self.T_cap = None if u is None else min(ocp.model.thrust_for_speed(u), ocp.vessel.T_max)
        self.u_plan = u
        self.__dict__.pop("order_model", None)  # its transit speed (Targeting.order_model)

    @property
    def speed_limit(self) -> float:
        """The highest surge speed the plan may use (m/s): the cap requested, else the
        vessel's ``u_max``."""
        u_max = self.ocp.vessel.u_max
        return u_max if self.u_cap is None else min(self.u_cap, u_max)

    @property
    def U_go(self) -> float:
        """Transit speed of the plan's time-to-go estimates (m/s): the preset's ``U_go``,
        at most the cap."""
        U = self.params.weights.U_go
        return U if self.u_plan is None else min(U, self.u_plan)

    def _capped(self, speed: float) -> float:
        """``speed`` (m/s) at most the cap (unchanged without one)."""
        return speed if self.u_plan is None else min(speed, self.u_plan)

    def _cap_parameters(self, p: np.ndarray) -> np.ndarray:
        """``p`` with the terminal cost's ``inv_U_go`` from :attr:`U_go` (in place; nothing
        changes without a cap)."""
        if self.u_plan is not None:
            self.ocp.unpack_par(p)["weights"][_INV_U_GO] = 1.0 / self.U_go
        return p
