"""CMA-ES that restarts when it stalls (:class:`StagnationRestartCMAES`): restart regimes, scouting and racing the
scouts by successive halving."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from besdrake.search.base import BestAndWorst, Optimizer
from besdrake.search.cmaes.core import CMAES

#: Restart regimes of :class:`StagnationRestartCMAES`.
_STAGNATION_REGIMES = ("large", "bipop", "local")


@dataclass(frozen=True)
class RaceStall:
    """When a run races its next group of start points because it stalls (:class:`StagnationRestartCMAES`'s
    ``race_stall``): the best reward since the current race began gained less than ``tol`` over the last
    ``generations`` generations, at least ``after`` generations into the race (its scouting is never cut short), and the
    run's best reward is still below ``below`` (e.g. minus the goal distance)."""

    generations: int
    tol: float
    below: float
    after: int = 0

    def __post_init__(self) -> None:
        if int(self.generations) != self.generations or self.generations < 1 or int(self.after) != self.after or self.after < 0:
            raise ValueError(f"race_stall generations must be a whole number >= 1 and after >= 0, got {self.generations!r}, {self.after!r}")
        if not (np.isfinite(self.tol) and self.tol >= 0 and np.isfinite(self.below)):
            raise ValueError(f"race_stall tol must be finite and >= 0 and below a finite reward, got {self.tol!r}, {self.below!r}")

    def stalled(self, race_best: list[float]) -> bool:
        """Whether a race whose best reward after each of its generations is ``race_best`` has stalled."""
        g = int(self.generations)
        return len(race_best) > g and len(race_best) >= self.after and race_best[-1] - race_best[-1 - g] < self.tol

    def to_dict(self) -> dict[str, Any]:
        return {"generations": int(self.generations), "tol": float(self.tol), "below": float(self.below), "after": int(self.after)}


class StagnationRestartCMAES(BestAndWorst, Optimizer):
    """CMA-ES that restarts when it stalls, from the next of several start points (a maximiser).

    Each *attempt* is a :class:`CMAES` (population ``popsize``, step ``sigma0``) started at
    ``starts[k % len(starts)]`` for the ``k``-th attempt, or, with ``restart_from_best``, at the best
    candidate so far (every attempt after the first). An attempt ends when the best reward it has seen
    has improved by less than ``tol`` over its last ``stagnation_generations`` generations (a plateau),
    after ``max_generations`` generations (``0``: no such cap), or when ``cma`` stops it. Meant for
    multi-modal landscapes where a run either finds the good basin early or creeps along a bad one
    (e.g. a family of poor movements that the search keeps stretching), so one budget is spent on
    several short attempts instead of one long one.

    Restart regimes (``regimes``):

    * ``"large"`` (default): every attempt has step ``sigma0``; ``popsize_growth`` > 1 makes it IPOP-like,
      attempt ``k`` has population ``round(popsize * popsize_growth**k)``.
    * ``"bipop"``: after the first attempt, a restart is *small* (step ``sigma0 * 10**(-small_decades * u)``,
      ``u ~ U(0, 1)``, population ``popsize``, always from the best candidate so far: a local search of
      the best basin) whenever the episodes spent in small attempts are fewer than ``small_share`` times
      those spent in large ones, else *large* (step ``sigma0``, population ``round(popsize * popsize_growth**j)`` for the
      ``j``-th large restart, start point as above). After Hansen (2009), "Benchmarking a BI-population
      CMA-ES on the BBOB-2009 function testbed", with the restarts triggered by stagnation.
    * ``"local"``: a restart is small (as above) unless the last ``patience`` small attempts in a row
      each failed to raise the best reward so far by ``tol``: then one large restart, after which
      restarts are small again. A local search of the best basin that escalates to a large step only
      when it is stuck (instead of BIPOP's fixed share of episodes).

    Scouting (``scouts`` > 1): the first ``scouts`` attempts are independent short CMA-ES runs (step ``sigma0``,
    each from ``starts[k % len(starts)]``, at most ``scout_generations`` generations each, one after the other);
    then the scout with the best reward goes on (its CMA-ES state, not a fresh one) as the first attempt proper,
    and the restarts above follow. Meant for landscapes where the basin a run ends up in is decided early.
    With ``scout_halving`` the scouts are raced by successive halving (Jamieson & Talwalkar 2016): every scout
    runs ``scout_generations`` generations (a *rung*), then the better half of those that did not stall
    (rounded up) runs another ``scout_generations`` generations each, its own CMA-ES going on, and so on until
    one is left; it goes on as the first attempt proper. Four scouts cost 6 rungs of generations instead of 4.
    With ``switch_below`` (a reward; halving only), a scout that went on and then ended (stagnation, cap or ``cma``)
    with its best reward below it hands over to the best scout the race eliminated (the runner-up of the last rung
    first, then the earlier rungs' by rank), whose CMA-ES goes on where the race left it, instead of a restart from
    the best candidate: a run whose winning family of candidates cannot reach the goal tries the next within its budget.
    A scout switched to ends (``"behind"``) where it is still behind the run's best after ``stagnation_generations``
    generations, or, with rewards that are minus distances (the run's best below 0), more than twice as far after half
    as many: a hopeless family costs a few generations.
    With ``next_starts`` (rows; halving and ``switch_below`` only), further groups of ``scouts`` start points: where the
    scout that went on ends with the run's best reward still below ``switch_below``, the next group is raced the same
    way before any eliminated scout is switched to (its eliminated scouts go first in the reserve): a run whose raced
    families fall short tries other start points within its budget.
    With ``race_stall`` (a :class:`RaceStall`; ``next_starts`` only) the next group is raced also where the run stalls
    short of a goal without its winner ending far: the best reward since the current race began gained less than
    ``race_stall.tol`` over its last ``race_stall.generations`` generations (scouting over) while the run's best is still
    below ``race_stall.below``. A family that creeps towards the goal without reaching it hands over to other starts;
    the rule then alone decides when the next group races (a winner that ends far hands over to the eliminated scouts,
    and the restarts from the run's best creep on, until the rule says the race has stalled).

    ``fixed``: coordinates every attempt holds at its start point's values (:class:`CMAES`'s ``fixed``), so a start
    point's fixed values (e.g. which imitated movement it is) stay with every candidate of the attempts that begin there,
    a restart from the best included.

    Budget and stop belong to the caller (the loop): :meth:`stop` is never true. One Generator drives
    every attempt; :meth:`state_dict` saves the attempt counter and regime bookkeeping, the per-generation
    best of the current attempt and the inner CMA-ES, so a resumed run asks the same candidates as an
    uninterrupted one.
    """

    def __init__(
        self,
        starts: np.ndarray,
        sigma0: float,
        rng: np.random.Generator,
        *,
        popsize: int | None = None,
        bounds: np.ndarray | None = None,
        stagnation_generations: int = 20,
        tol: float = 0.01,
        max_generations: int = 0,
        restart_from_best: bool = False,
        cma_options: dict[str, Any] | None = None,
        popsize_growth: float = 1.0,
        regimes: str = "large",
        small_decades: float = 2.0,
        small_share: float = 1.0,
        patience: int = 2,
        scouts: int = 0,
        scout_generations: int = 10,
        scout_halving: bool = False,
        switch_below: float | None = None,
        next_starts: np.ndarray | None = None,
        race_stall: RaceStall | None = None,
        fixed: Sequence[int] = (),
    ) -> None:
        starts = np.atleast_2d(np.asarray(starts, dtype=float))
        next_starts = _checked_next_starts(next_starts, starts, scouts, scout_halving, switch_below)
        if race_stall is not None and next_starts is None:
            raise ValueError("race_stall needs next_starts (further groups of start points to race)")
        _check_settings(starts, sigma0, stagnation_generations, max_generations, tol, popsize_growth, regimes, small_decades,
                        small_share, patience, scouts, scout_generations)
        if switch_below is not None and not np.isfinite(switch_below):
            raise ValueError(f"switch_below must be a finite reward or None, got {switch_below!r}")
        self.n_params = starts.shape[1]
        bounds = None if bounds is None else np.asarray(bounds, dtype=float)
        if bounds is not None:
            for s in starts if next_starts is None else np.vstack([starts, next_starts]):
                CMAES._check_bounds(bounds, s)
        self._configure(starts, sigma0, popsize, bounds, stagnation_generations, tol, max_generations, restart_from_best,
                        cma_options, popsize_growth, regimes, small_decades, small_share, patience, scouts, scout_generations,
                        scout_halving, switch_below, next_starts, race_stall)
        self.fixed = tuple(int(i) for i in fixed)
        self.rng = rng
        self._start_bookkeeping()
        self._init_best(starts[0])
        self.inner = self._new_attempt(self.sigma0)

    def _configure(self, starts: np.ndarray, sigma0: float, popsize: int | None, bounds: np.ndarray | None,
                   stagnation_generations: int, tol: float, max_generations: int, restart_from_best: bool,
                   cma_options: dict[str, Any] | None, popsize_growth: float, regimes: str, small_decades: float,
                   small_share: float, patience: int, scouts: int, scout_generations: int, scout_halving: bool,
                   switch_below: float | None = None, next_starts: np.ndarray | None = None,
                   race_stall: RaceStall | None = None) -> None:
        """Set the settings (checked already)."""
        self.starts = starts
        self.sigma0 = float(sigma0)
        self.popsize = popsize
        self.bounds = bounds
        self.stagnation_generations = int(stagnation_generations)
        self.tol = float(tol)
        self.max_generations = int(max_generations)
        self.restart_from_best = bool(restart_from_best)
        self.cma_options = dict(cma_options or {})
        self.popsize_growth = float(popsize_growth)
        self.regimes = str(regimes)
        self.small_decades = float(small_decades)
        self.small_share = float(small_share)
        self.patience = int(patience)
        self.scouts = int(scouts)
        self.scout_generations = int(scout_generations)
        self.scout_halving = bool(scout_halving)
        self.switch_below = None if switch_below is None else float(switch_below)
        self.next_starts = next_starts
        self.race_stall = race_stall

    def _start_bookkeeping(self) -> None:
        """The attempt, scouting and regime bookkeeping of a fresh run."""
        #: successive halving (``scout_halving``): the rung, the scout now running, the scouts still to run in this rung
        #: (their CMA-ES and per-generation best; ``None``: a fresh scout from its start point) and those that finished it
        self.rung = 0
        self.current_scout = 0
        self.rung_queue: list[tuple[int, CMAES | None, list[float]]] = [(k, None, []) for k in range(1, self.scouts)] if self.scout_halving else []
        self.rung_done: list[tuple[int, CMAES, list[float]]] = []
        #: the scouts the race eliminated, best first (kept only with ``switch_below``): the families a run switches to
        self.reserve: list[tuple[int, CMAES, list[float]]] = []
        #: the current attempt's generations when it was switched to (None: not a switch)
        self.switched_at: int | None = None
        #: the race now running or decided: 0 the first (``starts``), g the g-th group of ``next_starts``
        self.race = 0
        #: episodes told so far, those told when the current race began, and the best reward since then after each
        #: generation (``race_stall``)
        self.told = 0
        self.race_episode = 0
        self.race_best: list[float] = []
        #: scouting: the best scout so far (its CMA-ES, and its per-generation best), kept to go on after the last scout
        self.kept: CMAES | None = None
        self.kept_best: list[float] = []
        #: the scout (attempt number) kept so far, and the one whose CMA-ES the current attempt continues (None: a fresh attempt)
        self.kept_scout: int | None = None
        self.continued_scout: int | None = None
        self.attempt = 0
        #: regime bookkeeping: regime of the current attempt, large restarts so far, episodes per regime
        self.regime = "large"
        self.n_large_restarts = 0
        self.evaluations = {"large": 0, "small": 0}
        #: "local" regimes: small attempts in a row that did not raise the best by ``tol``; best reward when the attempt began
        self.small_streak = 0
        self.attempt_start_best = -np.inf
        #: best reward of the current attempt after each of its generations
        self.attempt_best: list[float] = []
        #: one entry per finished attempt: start index (-1: best so far), generations, best reward, why it ended, regime, step, population
        self.attempt_history: list[dict[str, Any]] = []

    def scouting(self) -> bool:
        """True while the current attempt is one of the scouts (see the class docstring)."""
        if self.scouts > 1 and self.scout_halving:
            return self.current_scout >= 0
        return self.scouts > 1 and self.attempt < self.scouts

    def _start_point(self) -> tuple[int, np.ndarray]:
        if (self.restart_from_best or self.regime == "small") and self.attempt > 0 and np.isfinite(self._best_reward) and not self.scouting():
            return -1, self._best_params.copy()
        i = self.attempt % len(self.starts)
        return i, self.starts[i].copy()

    def scout_start(self, k: int) -> np.ndarray:
        """Start point of scout ``k``: scouts ``0 .. scouts - 1`` from ``starts``, later races' from ``next_starts``."""
        i = self._start_index(k)
        return (self.starts[i] if i < len(self.starts) else self.next_starts[i - len(self.starts)]).copy()

    def n_races(self) -> int:
        """Races a run may hold: the first, and one per group of ``scouts`` rows of ``next_starts``."""
        return 1 if self.next_starts is None else 1 + -(-len(self.next_starts) // self.scouts)

    def _new_attempt(self, sigma: float, x: np.ndarray | None = None) -> CMAES:
        """A fresh CMA-ES of step ``sigma`` from ``x`` (default: :meth:`_start_point`), clipped into the bounds."""
        if x is None:
            _, x = self._start_point()
        if self.bounds is not None:
            span = self.bounds[:, 1] - self.bounds[:, 0]
            x = np.clip(x, self.bounds[:, 0] + 1e-9 * span, self.bounds[:, 1] - 1e-9 * span)
        return CMAES(x, sigma, self.rng, popsize=self.attempt_popsize(), bounds=self.bounds, cma_options=self.cma_options,
                     fixed=self.fixed)

    def attempt_popsize(self) -> int | None:
        """Population of the current attempt (``None``: ``cma``'s default, not grown)."""
        if self.popsize is None or self.popsize_growth == 1.0 or self.regime == "small":
            return self.popsize
        k = self.attempt if self.regimes == "large" else self.n_large_restarts
        return max(2, int(round(self.popsize * self.popsize_growth**k)))

    def _next_regime(self) -> float:
        """Choose the regime of the next attempt (sets :attr:`regime`); returns its step size."""
        if self.regimes == "local":
            improved = self._best_reward - self.attempt_start_best >= self.tol
            self.small_streak = 0 if (self.regime == "large" or improved) else self.small_streak + 1
            if self.small_streak < self.patience:
                self.regime = "small"
                return self.sigma0 * 10 ** (-self.small_decades * float(self.rng.uniform()))
            self.small_streak = 0
        elif self.regimes == "bipop" and self.evaluations["small"] < self.small_share * self.evaluations["large"]:
            self.regime = "small"
            return self.sigma0 * 10 ** (-self.small_decades * float(self.rng.uniform()))
        self.regime = "large"
        if self.attempt > 0:
            self.n_large_restarts += 1
        return self.sigma0

    def ask(self) -> np.ndarray:
        return self.inner.ask()

    def stalled(self) -> str | None:
        """Why the current attempt should end now (``None``: it goes on)."""
        g = len(self.attempt_best)
        if self._race_stalled():
            return "race_stall"
        if self.inner.stop():
            return "cma"
        if self.max_generations and g >= self.max_generations:
            return "max_generations"
        G = self.stagnation_generations
        if g > G and self.attempt_best[-1] - self.attempt_best[-1 - G] < self.tol:
            return "stagnation"
        if self.scouting() and g >= self.scout_generations * (self.rung + 1 if self.scout_halving else 1):
            return "scout"
        if self.switched_at is not None and self._behind(g - self.switched_at):
            return "behind"
        return None

    def _race_stalled(self) -> bool:
        """Whether the run races its next group now because it stalls short of the goal (``race_stall``)."""
        rs = self.race_stall
        if rs is None or self.scouting() or self.race + 1 >= self.n_races() or not self._best_reward < rs.below:
            return False
        return rs.stalled(self.race_best)

    def race_start_episode(self) -> int:
        """The episodes told before the current race began where the run races when it stalls (``race_stall``), else
        0: a caller's own stall rule judges the current race from there."""
        return self.race_episode if self.race_stall is not None else 0

    def _behind(self, generations: int) -> bool:
        """Whether a scout switched to ``generations`` ago is too far behind the run's best to go on."""
        best, run_best, G = self.attempt_best[-1], self._best_reward, self.stagnation_generations
        if generations >= G and best < run_best:
            return True
        return generations >= G // 2 and run_best < 0 and best < 2 * run_best

    def tell(self, candidates: np.ndarray, rewards: np.ndarray) -> None:
        candidates = np.asarray(candidates, dtype=float)
        rewards = np.asarray(rewards, dtype=float).ravel()
        clean, failed = self._record_batch(candidates, rewards)
        self.inner.tell(candidates, rewards)
        self.evaluations[self.regime] += rewards.size
        prev = self.attempt_best[-1] if self.attempt_best else -np.inf
        ok = clean[~failed]
        self.attempt_best.append(max(prev, float(ok.max())) if ok.size else prev)
        self._count_race(rewards.size, float(ok.max()) if ok.size else -np.inf)
        why = self.stalled()
        if why is not None:
            halving = self.scout_halving and self.scouting()
            index, _ = self._start_point()
            if halving:
                index = self._start_index(self.current_scout)
            if self.continued_scout is not None:
                index = self._start_index(self.continued_scout)  # the scout's start point
            entry = {"start": index, "generations": len(self.attempt_best), "best_reward": float(self.attempt_best[-1]), "end": why}
            if halving:
                entry |= {"scout": self.current_scout, "rung": self.rung}
            if self.continued_scout is not None:
                entry["continues_scout"] = self.continued_scout
            if self.regimes != "large" or self.popsize_growth != 1.0:
                entry |= {"regime": self.regime, "sigma0": float(self.inner.sigma0), "popsize": int(self.inner.popsize0)}
            self.attempt_history.append(entry)
            if halving:
                self._next_scout(why)
                return
            if why == "scout" and (not self.kept_best or self.attempt_best[-1] > self.kept_best[-1]):
                self.kept, self.kept_best, self.kept_scout = self.inner, list(self.attempt_best), self.attempt
            rerace = why == "race_stall" or self._reraces(why)
            switch = not rerace and self._switches(why)
            self.attempt += 1
            self.attempt_best = []
            self.continued_scout = None
            self.switched_at = None
            if switch:
                k, cma, best = self.reserve.pop(0)
                self.inner, self.attempt_best, self.continued_scout, self.regime = cma, list(best), k, "large"
                self.switched_at = len(best)
            elif rerace:
                self._start_race()
                return
            elif self.scouting():
                self.inner = self._new_attempt(self.sigma0)
            elif self.scouts > 1 and self.attempt == self.scouts and self.kept is not None:
                # scouting is over: the best scout goes on (a large attempt)
                self.inner, self.attempt_best, self.continued_scout = self.kept, self.kept_best, self.kept_scout
                self.kept, self.kept_best, self.kept_scout = None, [], None
            else:
                self.inner = self._new_attempt(self._next_regime())
            self.attempt_start_best = float(self._best_reward)

    def _count_race(self, episodes: int, batch_best: float) -> None:
        """Count a told batch of ``episodes`` (best clean reward ``batch_best``) towards the current race."""
        self.told += int(episodes)
        if self.race_stall is not None:
            self.race_best.append(max(self.race_best[-1], batch_best) if self.race_best else batch_best)

    def _switches(self, why: str) -> bool:
        """Whether the attempt that just ended (``why``) hands over to the next eliminated scout (``switch_below``)."""
        return (self.switch_below is not None and self.continued_scout is not None and why != "scout" and bool(self.reserve)
                and self.attempt_best[-1] < self.switch_below)

    def _start_index(self, k: int) -> int:
        """The row of scout ``k``'s start point in ``starts`` (later races': ``len(starts)`` + its row of ``next_starts``)."""
        if k < self.scouts or self.next_starts is None:
            return k % len(self.starts)
        return len(self.starts) + (k - self.scouts) % len(self.next_starts)

    def _reraces(self, why: str) -> bool:
        """Whether the run races its next group of start points now (``next_starts``): a raced scout that went on has
        just ended (``why``) with the run's best still below ``switch_below``, and a group is left (never with
        ``race_stall``: that rule alone decides then)."""
        return (self.next_starts is not None and self.race_stall is None and self.race + 1 < self.n_races()
                and self.continued_scout is not None and why != "scout" and self._best_reward < self.switch_below)

    def _start_race(self) -> None:
        """Begin the next race: its first scout runs, the others queue for the first rung."""
        self.race += 1
        self.race_episode, self.race_best = self.told, []
        first = self.race * self.scouts
        self.rung, self.current_scout, self.rung_done = 0, first, []
        self.rung_queue = [(k, None, []) for k in range(first + 1, first + self.scouts)]
        self.attempt_best, self.continued_scout, self.switched_at, self.regime = [], None, None, "large"
        self.inner = self._new_attempt(self.sigma0, self.scout_start(first))
        self.attempt_start_best = float(self._best_reward)

    def _next_scout(self, why: str) -> None:
        """Successive halving: file the scout that just ended (``why``) and switch to the next one, the next rung,
        or, with one scout left (or none that did not stall), to the first attempt proper."""
        if why == "scout":
            self.rung_done.append((self.current_scout, self.inner, list(self.attempt_best)))
        self.attempt += 1
        if not self.rung_queue and len(self.rung_done) > 1:
            ranked = sorted(self.rung_done, key=lambda e: -e[2][-1])  # stable: an earlier scout wins a tie
            self.rung_queue = [(k, cma, best) for k, cma, best in ranked[: (len(ranked) + 1) // 2]]
            if self.switch_below is not None:  # the eliminated, the later rung's first
                self.reserve = list(ranked[(len(ranked) + 1) // 2:]) + self.reserve
            self.rung_done = []
            self.rung += 1
            if len(self.rung_queue) == 1:  # the race is decided
                self.rung_done, self.rung_queue = self.rung_queue, []
        if self.rung_queue:
            k, cma, best = self.rung_queue.pop(0)
            self.current_scout, self.attempt_best = k, list(best)
            self.inner = cma if cma is not None else self._new_attempt(self.sigma0, self.scout_start(k))
        else:  # scouting is over: the winner goes on as a large attempt (a fresh one if every scout stalled)
            self.current_scout = -1
            self.attempt_best = []
            if self.rung_done:
                k, cma, best = self.rung_done[0]
                self.inner, self.attempt_best, self.continued_scout = cma, list(best), k
                self.rung_done = []
            else:
                self.inner = self._new_attempt(self._next_regime())
        self.attempt_start_best = float(self._best_reward)

    @property
    def mean(self) -> np.ndarray:
        """Mean of the current attempt's search distribution."""
        return self.inner.mean

    def state_dict(self) -> dict[str, Any]:
        extra_cfg: dict[str, Any] = {}
        if self.popsize_growth != 1.0:
            extra_cfg["popsize_growth"] = self.popsize_growth
        if self.regimes != "large":
            extra_cfg |= {"regimes": self.regimes, "small_decades": self.small_decades}
            if self.small_share != 1.0:
                extra_cfg["small_share"] = self.small_share
            if self.regimes == "local":
                extra_cfg["patience"] = self.patience
        if self.scouts > 1:
            extra_cfg |= {"scouts": self.scouts, "scout_generations": self.scout_generations}
            if self.scout_halving:
                extra_cfg["scout_halving"] = True
        if self.switch_below is not None:
            extra_cfg["switch_below"] = self.switch_below
        if self.next_starts is not None:
            extra_cfg["next_starts"] = self.next_starts
        if self.race_stall is not None:
            extra_cfg["race_stall"] = self.race_stall.to_dict()
        if self.fixed:
            extra_cfg["fixed"] = list(self.fixed)
        halving_state: dict[str, Any] = {}
        if self.scouts > 1 and self.scout_halving:
            halving_state = {"halving": {
                "rung": self.rung, "current_scout": self.current_scout,
                "queue": [{"scout": k, "cma": None if c is None else c.state_dict(), "best": [float(v) for v in b]} for k, c, b in self.rung_queue],
                "done": [{"scout": k, "cma": c.state_dict(), "best": [float(v) for v in b]} for k, c, b in self.rung_done]}}
            if self.switch_below is not None:
                halving_state["halving"]["reserve"] = [{"scout": k, "cma": c.state_dict(), "best": [float(v) for v in b]}
                                                       for k, c, b in self.reserve]
                halving_state["halving"]["switched_at"] = self.switched_at
            if self.next_starts is not None:
                halving_state["halving"]["race"] = self.race
            if self.race_stall is not None:
                halving_state["halving"] |= {"told": self.told, "race_episode": self.race_episode,
                                             "race_best": [float(v) for v in self.race_best]}
        return {
            "type": "StagnationRestartCMAES",
            "config": {
                "starts": self.starts,
                "sigma0": self.sigma0,
                "popsize": self.popsize,
                "bounds": self.bounds,
                "stagnation_generations": self.stagnation_generations,
                "tol": self.tol,
                "max_generations": self.max_generations,
                "restart_from_best": self.restart_from_best,
                "cma_options": self.cma_options,
                **extra_cfg,
            },
            "attempt": self.attempt,
            "regime": {"regime": self.regime, "n_large_restarts": self.n_large_restarts, "evaluations": dict(self.evaluations),
                       **({"small_streak": self.small_streak, "attempt_start_best": float(self.attempt_start_best)} if self.regimes == "local" else {})},
            "attempt_best": [float(v) for v in self.attempt_best],
            "attempt_history": self.attempt_history,
            **self._best_state(),
            "inner": self.inner.state_dict(),
            **({"kept": None if self.kept is None else self.kept.state_dict(), "kept_best": [float(v) for v in self.kept_best],
                "kept_scout": self.kept_scout, "continued_scout": self.continued_scout} if self.scouts > 1 else {}),
            **halving_state,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "StagnationRestartCMAES":
        if state.get("type") != "StagnationRestartCMAES":
            raise ValueError(f"not a StagnationRestartCMAES state (type={state.get('type')!r})")
        cfg = state["config"]
        inner = CMAES.from_state(state["inner"])
        opt = cls.__new__(cls)
        opt.n_params = inner.n_params
        opt._configure(np.atleast_2d(np.asarray(cfg["starts"], dtype=float)), float(cfg["sigma0"]), cfg["popsize"],
                       None if cfg["bounds"] is None else np.asarray(cfg["bounds"], dtype=float),
                       int(cfg["stagnation_generations"]), float(cfg["tol"]), int(cfg["max_generations"]),
                       bool(cfg["restart_from_best"]), dict(cfg["cma_options"]), float(cfg.get("popsize_growth", 1.0)),
                       str(cfg.get("regimes", "large")), float(cfg.get("small_decades", 2.0)),
                       float(cfg.get("small_share", 1.0)), int(cfg.get("patience", 2)), int(cfg.get("scouts", 0)),
                       int(cfg.get("scout_generations", 10)), bool(cfg.get("scout_halving", False)),
                       None if cfg.get("switch_below") is None else float(cfg["switch_below"]),
                       None if cfg.get("next_starts") is None else np.atleast_2d(np.asarray(cfg["next_starts"], dtype=float)),
                       None if cfg.get("race_stall") is None else RaceStall(**cfg["race_stall"]))
        opt.fixed = tuple(int(i) for i in cfg.get("fixed", ()))
        hv = state.get("halving", {})

        def _cma(d):
            if d is None:
                return None
            c = CMAES.from_state(d)
            c.rng = inner.rng  # one Generator drives every attempt
            return c

        opt.rung = int(hv.get("rung", 0))
        opt.current_scout = int(hv.get("current_scout", -1))
        opt.rung_queue = [(int(e["scout"]), _cma(e["cma"]), [float(v) for v in e["best"]]) for e in hv.get("queue", [])]
        opt.rung_done = [(int(e["scout"]), _cma(e["cma"]), [float(v) for v in e["best"]]) for e in hv.get("done", [])]
        opt.reserve = [(int(e["scout"]), _cma(e["cma"]), [float(v) for v in e["best"]]) for e in hv.get("reserve", [])]
        opt.switched_at = None if hv.get("switched_at") is None else int(hv["switched_at"])
        opt.race = int(hv.get("race", 0))
        opt.told, opt.race_episode = int(hv.get("told", 0)), int(hv.get("race_episode", 0))
        opt.race_best = [float(v) for v in hv.get("race_best", [])]
        opt.kept = None if state.get("kept") is None else CMAES.from_state(state["kept"])
        if opt.kept is not None:
            opt.kept.rng = inner.rng  # one Generator drives every attempt
        opt.kept_best = [float(v) for v in state.get("kept_best", [])]
        opt.kept_scout = None if state.get("kept_scout") is None else int(state["kept_scout"])
        opt.continued_scout = None if state.get("continued_scout") is None else int(state["continued_scout"])
        reg = state.get("regime", {})  # absent in states written before the regimes existed
        opt.regime = str(reg.get("regime", "large"))
        opt.n_large_restarts = int(reg.get("n_large_restarts", state["attempt"]))
        ev = reg.get("evaluations", {})
        opt.evaluations = {"large": int(ev.get("large", 0)), "small": int(ev.get("small", 0))}
        opt.small_streak = int(reg.get("small_streak", 0))
        opt.attempt_start_best = float(reg.get("attempt_start_best", -np.inf))
        opt.attempt = int(state["attempt"])
        opt.attempt_best = [float(v) for v in state["attempt_best"]]
        opt.attempt_history = [dict(e) for e in state["attempt_history"]]
        opt._restore_best(state)
        opt.inner = inner
        opt.rng = inner.rng
        return opt


def _checked_next_starts(next_starts, starts: np.ndarray, scouts: int, scout_halving: bool, switch_below) -> np.ndarray | None:
    """``next_starts`` as a finite (k, n) array (None stays None); ValueError unless the run races with a switch."""
    if next_starts is None:
        return None
    rows = np.atleast_2d(np.asarray(next_starts, dtype=float))
    if rows.size == 0 or rows.shape[1] != starts.shape[1] or not np.isfinite(rows).all():
        raise ValueError(f"next_starts must be a non-empty finite (k, {starts.shape[1]}) array, got shape {rows.shape}")
    if scouts < 2 or not scout_halving or switch_below is None:
        raise ValueError("next_starts needs raced scouts (scouts >= 2, scout_halving) and switch_below")
    return rows


def _check_settings(starts: np.ndarray, sigma0: float, stagnation_generations: int, max_generations: int, tol: float,
                    popsize_growth: float, regimes: str, small_decades: float, small_share: float, patience: int,
                    scouts: int, scout_generations: int) -> None:
    """ValueError for a setting of :class:`StagnationRestartCMAES` out of its range."""
    if starts.size == 0 or not np.isfinite(starts).all():
        raise ValueError(f"starts must be a non-empty finite (k, n) array, got {starts!r}")
    if not (np.isfinite(sigma0) and sigma0 > 0):
        raise ValueError(f"sigma0 must be a positive finite step size, got {sigma0!r}")
    if stagnation_generations < 1 or max_generations < 0:
        raise ValueError(f"stagnation_generations must be >= 1 and max_generations >= 0, got {stagnation_generations}, {max_generations}")
    if not (np.isfinite(tol) and tol >= 0):
        raise ValueError(f"tol must be a finite number >= 0, got {tol!r}")
    if not (np.isfinite(popsize_growth) and popsize_growth >= 1):
        raise ValueError(f"popsize_growth must be a finite number >= 1, got {popsize_growth!r}")
    if regimes not in _STAGNATION_REGIMES:
        raise ValueError(f"regimes must be one of {_STAGNATION_REGIMES}, got {regimes!r}")
    if not (np.isfinite(small_decades) and small_decades >= 0):
        raise ValueError(f"small_decades must be a finite number >= 0, got {small_decades!r}")
    if not (np.isfinite(small_share) and small_share > 0):
        raise ValueError(f"small_share must be a finite number > 0, got {small_share!r}")
    if int(patience) != patience or patience < 1:
        raise ValueError(f"patience must be an integer >= 1, got {patience!r}")
    if int(scouts) != scouts or scouts < 0 or int(scout_generations) != scout_generations or scout_generations < 1:
        raise ValueError(f"scouts must be an integer >= 0 and scout_generations >= 1, got {scouts!r}, {scout_generations!r}")
