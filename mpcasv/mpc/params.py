"""Parameters of the MPC (frozen, validated from the ``mpc-*.toml`` presets).

Every weight and horizon setting of :mod:`mpcasv.mpc` lives here, the solver's in
:mod:`mpcasv.mpc.solver_params`; docs/mpc.md gives the equations each one enters. Units are
SI; costs are per second of the horizon (the stage cost is multiplied by the stage length
``dt``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from mpcasv.config import Flag, NonNeg, NonNegInt, Pos, PosInt, TransitSpeed, frozen
from mpcasv.estimation.current import CurrentObserverParams
from mpcasv.hybrid.avoidance import AvoidanceParams
from mpcasv.hybrid.domains import DomainParams
from mpcasv.models.acoustics import NavParams
from mpcasv.mpc.solver_params import SolverParams


@frozen
class HorizonParams:
    """Prediction horizon: ``N`` stages of ``dt`` s, RK4 with ``n_sub`` sub-steps per stage.

    RK4 is stable on Gretha's fastest pole (2.4 1/s straight ahead at 2.5 m/s, 2.7 in a
    full-rudder turn) for sub-steps up to about 1.0 s: keep ``dt / n_sub <= 1``. ``n_sub`` is
    a floor: the plan takes more sub-steps where the run's vessel has a faster rigid-body pole
    over its manoeuvring envelope
    (:attr:`mpcasv.mpc.problem.OCP.n_sub`; the actuators' lags do not count: the plan has
    none, it drives the set-points through their rates).

    ``steering`` says what the plan's eighth state is (docs/mpc.md, "Variables and dynamics",
    M1h): ``"rudder"`` the steering angle, driven open loop through its rate; ``"heading"``
    the heading reference handed to the execution level, whose yaw PD (the run's execution
    gains) sets the steering angle inside the prediction; ``"auto"`` (default) ``"heading"``
    for a course-unstable hull (:func:`~mpcasv.models.envelope.course_instability`: Fossen's
    Otter, whose yaw an open-loop plan cannot hold over 4-s stages), else ``"rudder"``
    (Gretha, dune-otter: the plan as before).

    ``tail_N`` coarse stages of ``tail_m * dt`` s each follow the ``N`` fine ones (issue 16
    item 2, docs/mpc.md "Long horizon", eq. M1t): a horizon of ``(N + tail_N tail_m) dt`` s
    that reaches the next AUV. A coarse stage holds its command rates (move blocking) and is
    integrated as ``tail_m`` fine stages, so the model and its accuracy are the same; its
    cost is the sum of theirs, its range constraints are at its start only. ``tail_N = 0``
    (the presets): the uniform horizon, unchanged.
    """

    N: PosInt = 15
    dt: Pos = 4.0
    n_sub: PosInt = 4
    steering: Literal["auto", "rudder", "heading"] = "auto"
    tail_N: NonNegInt = 0
    tail_m: PosInt = 5


@frozen
class FixRateParams:
    """Smooth fix-rate model (docs/mpc.md eq. M3).

    ``rho = p_good / T0 * sig((d_fix - d) / w_range) * sig((T_quiet - T) / w_thrust)``

    Attributes
    ----------
    range_kind : {"acoustic", "target"}
        ``acoustic``: ``d`` is the slant range and ``d_fix`` the acoustic channel's good range
        ``d1``. ``target``: ``d`` is the horizontal range and ``d_fix = r_t + eps_plus``, the
        geometric part of Paper 2's reliable-fix rule (eq. 9): a "fix" is a visit.
    w_range : float
        Width of the range sigmoid (m).
    T_quiet : float or None
        Thrust below which the propeller counts as off (N); None: the execution level's
        propeller-on threshold.
    w_thrust : float
        Width of the plan's thrust sigmoids (N: quiet M3, deadband M4b, running M4c), at most
        a third of the execution level's propeller-on threshold ``T_on`` (or of ``T_quiet``
        if lower)
        (:data:`~mpcasv.mpc.smooth.W_T_OF_T_ON`), so that a stopped propeller counts as
        quiet (>= 95 %) on any boat. The presets' 4 N is Gretha's (0.29 of her 14-N
        threshold); uncapped, it was 3.4 times dune-otter's 1.2 N: its plan counted 57 % of
        the fixes with the propeller off and 28 % while running at a fifth of full thrust,
        and hovered at r_outer (session 11).
    noisy_fixes : bool
        ``acoustic`` model only: fixes while the propeller runs count too, at the channel's
        ``propeller_factor`` (every fix the simulator delivers). False (presets): only fixes
        with the propeller off count, as in Paper 2's reliable fix (eq. 9) and the comparison's
        reliable-fix age; with True Case 1's standby fraction fell from 0.88 to 0.47
        (``mpc-single-sim``, seed 0).
    inset : float
        ``target`` model: the range sigmoid is centred this far (m) inside ``r_t +
        eps_plus`` (0, default: on it), so that the plan does not stop a few metres outside
        the reliable-fix circle, where the smooth rate still promises fixes the simulator
        does not give (preset mpc-multi-variance: 6 m).
    """

    range_kind: Literal["acoustic", "target"] = "acoustic"
    w_range: Pos = 10.0
    T_quiet: Pos | None = None
    w_thrust: Pos = 4.0
    noisy_fixes: Flag = False
    inset: NonNeg = 0.0


@frozen
class WeightParams:
    """Cost weights (docs/mpc.md eq. M4); all per second of horizon.

    Attributes
    ----------
    age : float
        On the sum of the AUVs' expected fix ages, per ``tau_ref`` seconds of age.
    worst : float
        On the worst (largest) expected fix age (epigraph variable), per ``tau_ref``.
    tau_ref : float
        Fix age that costs ``age`` (s).
    thrust : float
        On thrust, per ``T_max``.
    power : float
        On thrust x surge speed, per ``T_max u_max``.
    dT, ddelta : float
        On the squared command rates, per rate limit.
    slack : float
        L1 (exact) penalty on the soft-constraint slacks, per metre.
    deadband : float
        On thrusts between the propeller-on threshold and the execution level's transit thrust
        floor (smooth bump): the execution level cannot hold them, and without this term the
        plan "creeps" at a few newtons while counting as quiet.
    running : float
        Per second with the propeller running, whatever the thrust (noise, wear): favours
        short brisk transits and long standby over slow economical ones.
    floor : float
        On the planned ground surge below ``speed_min`` while the propeller runs:
        ``floor * sig((T - T_on) / w_T) * (speed_min - u)_+^2`` per (m/s)^2 (eq. M4f): the
        TRANSIT command clips its speed to ``[speed_min, u_max]`` (the execution level's speed
        loop tracks a positive ground speed), so a plan that thrusts lightly upstream and drifts
        back is one the execution level cannot follow. Soft: from standstill the boat
        accelerates from ``u = 0`` with the propeller on. Compiled in (not a runtime weight);
        0 (default) leaves the term out. Opt-in, measured worse at 10 (session 29: plan and
        execution closer in currents, but fewer reliable fixes and 2.6 times the collision-
        domain time on the paper cases; docs/mpc.md "Known problems", strong currents).
    tail : float
        Length of the tail the terminal cost stands for (s).
    terminal : {"projected", "integral", "visit"}
        Terminal cost (docs/mpc.md eq. M7): ``projected`` values the tail on the target AUV's
        projected fix age ``tau + t_go``; ``integral`` (M7i) on the fix age integrated until
        the target's next fix, ``tau (t_go + tail) + (t_go + tail)^2 / 2``, the running age
        cost's own cost-to-go: as ``projected`` near the target circle with a fresh fix, a
        pull that grows with the age and the distance (its accrual ``tau t_go + t_go^2 / 2``
        off for a step under a threat, as ``stand``); ``visit``: all ages grow through the
        tail except the target's, whose visit saves ``(tail - t_go)+ (tau + t_go)`` (kept
        for comparison: with ages beyond ``tail`` it rewards arriving late).
    U_go : float
        Speed used to turn the distance to an AUV's target circle into a time to go (m/s).
    stand : float
        One AUV (docs/mpc.md eq. M7s): seconds of fix age, per ``tau_ref``, for each second
        by which the ASV, standing still where the plan ends, could stand less than one
        horizon before the AUV (constant velocity) reaches ``r_outer`` or, if its path
        crosses it, the collision domain. Without it (0, the default here; 20 in the
        single-AUV presets since session 12) the terminal cost sees the fix age where the
        plan ends but not that the ASV must leave soon after: each plan moved first and
        stood by last, and the next plan did the same. Set to 0 for a step while an AUV
        threatens the ASV adrift (a pursuer re-aims at the ASV).
    """

    age: NonNeg = 1.0
    worst: NonNeg = 0.0
    tau_ref: Pos = 100.0
    thrust: NonNeg = 0.3
    power: NonNeg = 0.3
    dT: NonNeg = 0.02
    ddelta: NonNeg = 0.02
    slack: Pos = 10.0
    deadband: NonNeg = 1.0
    running: NonNeg = 0.0
    floor: NonNeg = 0.0
    tail: NonNeg = 60.0
    terminal: Literal["projected", "integral", "visit"] = "projected"
    U_go: Pos = 2.5
    stand: NonNeg = 0.0


@frozen
class OrderParams:
    """The visiting-order top level (``target_rule = "order"``; :mod:`mpcasv.mpc.order`, eq.
    O1, docs/mpc.md "Visiting order").

    Attributes
    ----------
    window : float
        Window ``W`` over which the orders of visits (repeated tours) are compared (s).
    stay : float
        Standby the top level expects at each AUV it visits (s).
    hysteresis : float
        The run's first target (not committed) gives way only to an order at least this
        fraction cheaper than the best order that starts by staying with it (issue 16 item
        6). A committed target, once served, is left (session 16; docs/mpc.md "Visiting
        order").
    nav : float
        Cost per second of one ``V_ref = eps_a^2 / 8 tau_ref^4`` of an AUV's navigation
        variance (per axis; ``tau_ref`` of the weights), against the OCP's energy terms at
        ``U_go`` per second of transit (``e_go``).
    """

    window: Pos = 600.0
    stay: NonNeg = 30.0
    hysteresis: NonNeg = 0.02
    nav: Pos = 1.0


@frozen
class VarianceParams:
    """Weights of the navigation-variance objective (``objective = "variance"``;
    :mod:`mpcasv.mpc.variance`, docs/mpc.md "Objective: navigation uncertainty"). They enter
    as parameters (retuning needs no recompilation).

    Attributes
    ----------
    nav : float
        On the sum of the AUVs' navigation variances ``eps_a^2 / 8 tau^4`` (M4n and the tail
        M7c), per the variance at ``weights.tau_ref``, per s.
    near : float
        Per s within ``NEAR_BUFFER`` (10 m) of an AUV's anti-collision bound (M4d).
    """

    nav: NonNeg = 1.0
    near: NonNeg = 0.2


@frozen
class MPCParams:
    """Preset of ``mpc-single`` / ``mpc-multi``.

    Attributes
    ----------
    domain : DomainParams
        The donut (single AUV: ``r_inner <= r <= r_outer``) or the anti-collision radii (several
        AUVs: ``r >= r_avoid``), from :mod:`mpcasv.hybrid.domains`.
    avoidance : AvoidanceParams
        Which anti-collision radius (the papers' fixed one, or uncertainty-aware); the MPC
        evaluates it at every stage along the planned bearing.
    vessel, execution : str or None
        Vessel model and execution-level parameters (shipped names or TOML paths, relative to
        the preset's folder). None (the shipped presets): the run's, i.e. the scenario's
        ``asv.vessel`` / ``asv.execution`` or the deploy configuration's; a preset that names
        another boat than the run's is refused (one vessel per run). Outside a run (an
        ``MPCController`` built directly) None means the shipped Gretha.
    T_ramp : float
        Time to ramp thrust from zero to ``T_max`` in the plan (s): the thrust rate limit.
    standby_time : float
        The command is STANDBY when the planned thrust stays below the propeller-on threshold
        for this long (s).
    min_dwell : float
        The dwell rule (s; 0: none): a commanded mode (STANDBY or TRANSIT) is kept at least
        this long before the plan may change it, except a TRANSIT for AVOIDANCE, the escape
        manoeuvre and fallback steps, which are never held back (docs/mpc.md, "Mode
        dwell"). Against the plan's STANDBY/TRANSIT chatter (1-4 s standbys and transits).
    margin : float
        The plan keeps this far inside the donut (m): ``r_inner + margin <= r`` (and
        ``r <= r_outer - margin``); the fallback check uses the radii themselves.
    lookahead : float
        The TRANSIT waypoint is the planned position this far ahead (s), less the planned
        current's drift over that time (the point as seen in the water: the execution
        level's line of sight points the bow at the waypoint, and the plan's bow points
        there, crabbing; not with ``course_control``) ...
    min_carrot : float
        ... pushed out to at least this distance from the ASV (m) so that line-of-sight
        guidance has a well-defined bearing.
    course_control : bool
        Whether the execution level steers the course over the ground at the TRANSIT
        waypoint (DUNE's PathController ``Course Control``: true in DUNE's defaults, false in
        its stock Otter configuration), so that it compensates the crab angle itself: the
        waypoint is then the planned ground point, not less the current's drift (which would
        compensate it twice). False (default): it points the bow at the waypoint, as the
        simulator's and the SITL's line of sight do (docs/deploy.md, "Course control"); true
        in a simulation is the crab-blind waypoint of before session 28 (an ablation).
    speed_min : float
        Lowest speed cap handed to the execution level (m/s).
    speed_rule : {"max", "ahead", "mean", "plan"}
        The TRANSIT speed: the largest planned surge speed within ``lookahead`` (``max``,
        the presets), the same from the plan's first stage on (``ahead``: without the
        measured speed of now, which ``max`` always includes) or its time average over
        ``lookahead`` (``mean``), caps over the lookahead; or ``plan``: the planned surge
        speed ``speed_lead`` seconds ahead (linear between stages), a reference that follows
        the plan's speed profile because the MPC re-issues it every control period. With
        ``max`` the execution level holds the speed the plan is about to give up (the plan
        glides at low thrust while the boat keeps its speed; the cap is never below the
        speed of now, so a TRANSIT never slows the boat): docs/mpc.md, "Plan following".
        Every rule is clipped to ``[speed_min, u_max]``; the execution level's eq. 3.1 still
        slows turns below it.
    speed_lead : float
        How far ahead (s) the planned speed (``speed_rule = "plan"``) and, with M1h
        (``horizon.steering``), the planned heading reference are read for the command: the
        end of the coming control period (1 s in ``simulate`` and the deploy default).
    speed : float
        Transit speed cap of the hybrid fallback controller (m/s).
    T_standby : float
        Minimum standby time of the hybrid fallback (multi-AUV) controller (s).
    tau_served : float
        Several AUVs: the target AUV (the one the terminal cost sends the ASV to) is kept until
        it has had a fix since it was chosen (in expectation) and its expected fix age is
        below this (s); then the AUV with the largest projected fix age becomes the target
        (:mod:`mpcasv.mpc.target`; the run's first target, AUV 0, needs no fix since).
    dwell_max : float
        ... or once the ASV has spent this long within the target's target domain (s): a
        moving AUV may keep the expected fix age above ``tau_served``.
    target_rule : {"age", "order"}
        Which AUV becomes the target once the current one is served: ``age`` (default, the
        shipped presets): the largest projected fix age ``tau_i + t_go,i`` among those above
        ``tau_served``; ``order`` (opt-in, preset ``mpc-multi-order``): the first AUV of the
        cheapest visiting order over ``order.window`` (:mod:`mpcasv.mpc.order`, eq. O1).
    first_tour : bool
        ``age`` rule, four AUVs or more (:data:`mpcasv.mpc.target.FIRST_TOUR_MIN_AUVS`): while
        some AUV the ASV can reach has not been visited since the run began, the target is
        the first AUV of the path through those, on to the oldest AUV already visited, with
        the least sum of arrival distances (eq. M9t, :mod:`mpcasv.mpc.target`; the age
        rule then mostly repeats that cycle); False: the largest projected age from the
        start.
    order : OrderParams
        The visiting-order top level (``target_rule = "order"`` only).
    navigation : NavParams
        The AUVs' inertial navigation as the top level and the variance objective assume it
        (``eps_a``, m/s^2: the variance growth of eqs. O1, M2', M4n, M7c; the thesis's MRU
        value by default, as the scenarios').
    cv_forecast_max : float
        Without the estimator's own forecast (along the AUV's plan) the visiting order and
        the variance tail extrapolate an AUV's velocity this far (s) and then hold its
        position (an AUV on a lawn-mower pattern turns every minute or two).
    objective : {"age", "variance"}
        ``age`` (default, the shipped presets): the expected-fix-age problem (M2, M4, M7);
        ``variance`` (opt-in, preset ``mpc-multi-variance``): the AUVs' navigation variance
        (M2', M4n, M4d, M7c; :mod:`mpcasv.mpc.variance`), a different compiled problem.
    variance : VarianceParams
        Its weights (``objective = "variance"`` only).
    explore_every : float
        While the plan stands still, also solve from a guess heading for the AUV with the
        largest projected fix age this often (s; 0: never). Standing still is a local minimum.
    fix_age_source : {"model", "estimate", "observed"}
        Initial fix ages: ``model`` integrates the same expected-fix-age model (eq. M2) on the
        observed states (works with any estimator, also ``perfect``); ``estimate`` takes
        ``obs.t - t_last_fix`` of each AUV estimate (needs an estimator fed by fixes);
        ``observed`` integrates M2 as ``model`` and, when the ASV's own USBL reports a new
        fix (``Observation.usbl_fix_times``) while the ASV was quiet within that AUV's
        reliable-fix range as it believes it (Paper 2 eq. 9), sets that AUV's age to the
        fix's and counts it as served (M2o, docs/mpc.md; in ``mpcasv deploy`` the fixes are
        DUNE's ``UsblFixExtended``); refused with ``objective = "variance"`` and by ``mpcasv
        replay`` of a deploy log without fix times (written before the deploy read them), and
        a step whose observation has no fix times raises ValueError.
    current : {"estimated", "oracle", "zero"}
        The current the plan assumes (constant over the horizon; issue 16 item 1):
        ``estimated`` (default): the on-board observer's estimate from the ASV's own motion
        (:mod:`mpcasv.estimation.current`); ``oracle``: the simulator's true current at the
        ASV (ablations only: the controller asks for it and the simulator puts it into the
        observation; refused where no observation carries it, as in the field); ``zero``:
        still water (the MPC before issue 16).
    initial_actuators : {"observed", "trim"}
        The plan's initial thrust and steering: ``observed`` (default) takes
        ``Observation.actuators`` when the observation carries them (simulation; a deploy
        with thruster and steering feedback), else as ``trim``: trim thrust for the speed
        through the water while the propeller runs, steering from the previous plan (the MPC
        before; docs/mpc.md "Plan following" has both measured).
    observer : CurrentObserverParams
        Tuning of the current observer (run in every mode; its estimate is logged as
        ``mpc_est_cur_N`` / ``mpc_est_cur_E``, the plan's current as ``mpc_cur_N`` /
        ``mpc_cur_E``).
    """

    domain: DomainParams
    avoidance: AvoidanceParams = AvoidanceParams()
    horizon: HorizonParams = HorizonParams()
    fix: FixRateParams = FixRateParams()
    weights: WeightParams = WeightParams()
    solver: SolverParams = SolverParams()
    vessel: str | None = None
    execution: str | None = None
    T_ramp: Pos = 4.0
    standby_time: Pos = 4.0
    min_dwell: NonNeg = 5.0
    margin: NonNeg = 5.0
    lookahead: Pos = 15.0
    min_carrot: Pos = 25.0
    course_control: Flag = False
    speed_min: TransitSpeed = 0.5
    speed_rule: Literal["max", "ahead", "mean", "plan"] = "max"
    speed_lead: Pos = 1.0
    speed: TransitSpeed = 2.5
    T_standby: Pos = 10.0
    tau_served: Pos = 10.0
    dwell_max: Pos = 45.0
    target_rule: Literal["age", "order"] = "age"
    first_tour: Flag = True
    order: OrderParams = OrderParams()
    navigation: NavParams = NavParams()
    cv_forecast_max: Pos = 60.0
    objective: Literal["age", "variance"] = "age"
    variance: VarianceParams = VarianceParams()
    explore_every: NonNeg = 5.0
    fix_age_source: Literal["model", "estimate", "observed"] = "model"
    current: Literal["estimated", "oracle", "zero"] = "estimated"
    initial_actuators: Literal["observed", "trim"] = "observed"
    observer: CurrentObserverParams = CurrentObserverParams()

    @property
    def needs_current_oracle(self) -> bool:
        """The plan reads the simulator's true current (``current = "oracle"``)."""
        return self.current == "oracle"

    @property
    def needs_usbl_fixes(self) -> bool:
        """The fix ages read the ASV's own USBL fix times (``fix_age_source = "observed"``,
        M2o): the simulator's observations and the deploy's (DUNE's ``UsblFixExtended``)."""
        return self.fix_age_source == "observed"

    @model_validator(mode="after")
    def _observed_needs_ages(self) -> MPCParams:
        if self.fix_age_source == "observed" and self.objective == "variance":
            raise ValueError("fix_age_source = 'observed' needs objective = 'age': with the "
                             "variance objective the ages stand for navigation variances, "
                             "and a fix at range leaves some (M2'), which resetting to the "
                             "fix's age would drop")  # fmt: skip
        return self
