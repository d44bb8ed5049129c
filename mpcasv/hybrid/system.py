"""A small sampled hybrid automaton in the Goebel-Sanfelice-Teel form ``(C, F, D, G)``.

The papers write their controllers as hybrid systems (Paper 1 eqs. 1 and 11; Paper 2 eq. 11):
a flow set ``C`` and flow map ``F`` per mode, and jump sets ``D`` with jump maps ``G``. Here

- a :class:`Mode` carries the flow map ``F`` over one sample period, ``flow(state, dt)``, and
  optionally the rest of its flow set ``C`` (the mode test ``q == name`` is implicit);
- a :class:`Transition` is one edge of the jump set: ``D`` restricted to its source modes is
  ``guard(state)``, its jump map ``G`` is ``reset(state)``, and ``cause`` labels it in the log.

The state is any immutable object with a mode attribute ``q``: a frozen dataclass or a
``NamedTuple``. The automaton knows nothing else about it; it sets ``q`` to the target mode after
each reset. Time advances as hybrid time ``(t, j)``: :meth:`HybridAutomaton.step` first resolves
jumps at ``t`` (``j`` increases), then flows for ``dt``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Hashable, Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pandas only for the jump log: a solver worker (controller import) skips it
    import pandas as pd

__all__ = ["HybridAutomaton", "HybridError", "Jump", "Mode", "Transition", "ZenoError"]

State = Any
"""An immutable state with a mode attribute ``q`` (frozen dataclass or NamedTuple)."""


class HybridError(RuntimeError):
    """The hybrid system is ill-posed at a state (unknown mode, neither in C nor in D)."""


class ZenoError(HybridError):
    """More consecutive jumps at one instant than allowed (a jump chain that does not end)."""


@dataclasses.dataclass(frozen=True, slots=True)
class Jump:
    """One logged jump: at hybrid time ``(t, j)`` from ``from_mode`` to ``to_mode``.

    ``j`` counts the jumps since the log was last cleared (the first jump has ``j = 1``).
    """

    t: float
    j: int
    from_mode: Hashable
    to_mode: Hashable
    cause: str


@dataclasses.dataclass(frozen=True, slots=True)
class Mode:
    """A discrete mode ``q`` with its flow map and flow set.

    Attributes
    ----------
    name : hashable
        The value of ``state.q`` in this mode.
    flow : callable ``(state, dt) -> state``
        Flow map ``F`` integrated over ``dt`` seconds (must keep ``q``).
    flow_set : callable ``(state) -> bool``, optional
        Flow set ``C`` of this mode beyond ``q == name``; ``None`` means no further condition.
    """

    name: Hashable
    flow: Callable[[State, float], State]
    flow_set: Callable[[State], bool] | None = None


def _identity(state: State) -> State:
    return state


@dataclasses.dataclass(frozen=True, slots=True)
class Transition:
    """An edge of the jump set: from ``source`` to ``target`` when ``guard`` holds.

    Attributes
    ----------
    source : hashable, list/tuple/set of hashables, or None
        Mode(s) the edge leaves from (a tuple means several modes); ``None`` means every mode.
    target : hashable
        Mode after the jump.
    guard : callable ``(state) -> bool``
        The jump set ``D`` restricted to this edge.
    reset : callable ``(state) -> state``
        The jump map ``G`` (``q`` is then set to ``target``); identity by default.
    cause : str
        Label written in the jump log.
    """

    source: Hashable | Sequence[Hashable] | None
    target: Hashable
    guard: Callable[[State], bool]
    reset: Callable[[State], State] = _identity
    cause: str = ""

    @property
    def sources(self) -> tuple[Hashable, ...] | None:
        """The source modes as a tuple (a list, tuple or set means several), or ``None``."""
        if self.source is None:
            return None
        if isinstance(self.source, (list, tuple, set, frozenset)):
            return tuple(self.source)
        return (self.source,)

    def leaves(self, q: Hashable) -> bool:
        """Whether this edge starts in mode ``q``."""
        return self.sources is None or q in self.sources


def _with_mode(state: State, q: Hashable) -> State:
    if state.q == q:
        return state
    if dataclasses.is_dataclass(state):
        return dataclasses.replace(state, q=q)
    return state._replace(q=q)  # NamedTuple


class HybridAutomaton:
    """Modes, prioritised transitions and a jump log; advanced by :meth:`step`.

    Parameters
    ----------
    modes : sequence of Mode
        The discrete modes (unique names).
    transitions : sequence of Transition
        The jump edges; where several are enabled, the first in this order wins.
    max_jumps : int, default 8
        Most consecutive jumps at one instant before :class:`ZenoError` is raised.
    """

    def __init__(
        self, modes: Sequence[Mode], transitions: Sequence[Transition], max_jumps: int = 8
    ) -> None:
        self.modes = {m.name: m for m in modes}
        if len(self.modes) != len(modes):
            raise ValueError("mode names must be unique")
        for tr in transitions:
            if any(q not in self.modes for q in (tr.target, *(tr.sources or ()))):
                raise ValueError(f"transition {tr.cause!r} refers to an unknown mode")
        if max_jumps < 1:
            raise ValueError("max_jumps must be >= 1")
        self.transitions = tuple(transitions)
        self.max_jumps = max_jumps
        self._log: list[Jump] = []

    @property
    def jumps(self) -> tuple[Jump, ...]:
        """All jumps so far, in order."""
        return tuple(self._log)

    def clear_log(self) -> None:
        """Forget the logged jumps (the hybrid jump counter restarts at 0)."""
        self._log.clear()

    def jump_log(self) -> pd.DataFrame:
        """The jump log as a DataFrame with columns ``t, j, from_mode, to_mode, cause``."""
        import pandas as pd

        cols = [f.name for f in dataclasses.fields(Jump)]
        return pd.DataFrame([dataclasses.astuple(jp) for jp in self._log], columns=cols)

    def enabled(self, state: State) -> Transition | None:
        """The highest-priority transition whose jump set contains ``state``, if any."""
        self._mode(state)
        return next((tr for tr in self.transitions if tr.leaves(state.q) and tr.guard(state)), None)

    def step(self, t: float, state: State, dt: float) -> State:
        """Jump while the state is in ``D`` (at time ``t``), then flow for ``dt`` seconds.

        Raises
        ------
        ZenoError
            More than ``max_jumps`` consecutive jumps at ``t``.
        HybridError
            The mode is unknown, or after the jumps the state is outside its flow set ``C``.
        """
        n_jumps = 0
        while (tr := self.enabled(state)) is not None:
            if n_jumps == self.max_jumps:
                raise ZenoError(
                    f"more than {self.max_jumps} consecutive jumps at t = {t} "
                    f"(next: {tr.cause!r} from q = {state.q!r})"
                )
            q_from = state.q
            state = _with_mode(tr.reset(state), tr.target)
            self._log.append(Jump(float(t), len(self._log) + 1, q_from, tr.target, tr.cause))
            n_jumps += 1
        mode = self._mode(state)
        if mode.flow_set is not None and not mode.flow_set(state):
            raise HybridError(f"state in neither C nor D at t = {t}: {state!r}")
        return mode.flow(state, dt)

    def _mode(self, state: State) -> Mode:
        try:
            return self.modes[state.q]
        except KeyError:
            raise HybridError(f"unknown mode q = {state.q!r}") from None
