"""Solutions of hybrid systems as numpy arrays: :class:`Solution`, its
:class:`Jumps` table and :class:`Termination`.

A solution lives on a hybrid time domain: samples ``(t, j, x)`` in domain
order, ``t`` nondecreasing, ``j`` counting the jumps. At a jump the
pre-jump sample ``(t, j)`` is followed by the post-jump sample
``(t, j + 1)``: several samples share that ``t``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _hybsim

#: Names of the sample kinds (``Solution.kind_code`` indexes this tuple).
SAMPLE_KINDS = tuple(_hybsim.SAMPLE_KINDS)

_AT_JUMP = ("start", "end", "both", "nan")


def _interval(var: str, lo: Any, hi: Any, below: Any, above: Any) -> Tuple[Any, Any]:
    """The bounds of ``restrict_t``/``restrict_j`` (None: ``below``,
    ``above``); a reversed interval or a NaN bound selects nothing, which
    is a mistake, not an empty solution."""
    lo = below if lo is None else lo
    hi = above if hi is None else hi
    for name, bound in ((f"{var}_min", lo), (f"{var}_max", hi)):
        # A str bound failed inside numpy ("ufunc 'isnan' not supported ...").
        if isinstance(bound, (bool, np.bool_)) or not isinstance(bound, (int, float, np.number)):
            raise TypeError(f"restrict_{var}: {name} is a number or None, not {type(bound).__name__}")
    if np.isnan(lo) or np.isnan(hi):
        raise ValueError(f"restrict_{var}: a bound is NaN ({var}_min={lo}, {var}_max={hi})")
    if lo > hi:
        raise ValueError(
            f"restrict_{var}: {var}_min = {lo} is greater than {var}_max = {hi}; "
            f"the interval is {var}_min <= {var} <= {var}_max"
        )
    return lo, hi


@dataclass(frozen=True)
class Termination:
    """Where and why a solution ended.

    ``cause`` is one of ``"horizon_t"``, ``"horizon_j"``,
    ``"zeno_suspected"``, ``"cannot_flow_or_jump"``, ``"stopped_by_sink"``;
    ``details`` holds the cause's fields (for Zeno: ``rule``, ``rule_name``,
    ``detail``).
    """

    cause: str
    t: float
    j: int
    message: str
    help: str
    details: Dict[str, Any] = field(default_factory=dict)

    @classmethod
    def _from_dict(cls, d: Optional[Dict[str, Any]]) -> Optional["Termination"]:
        if d is None:
            return None
        d = dict(d)
        return cls(
            cause=d.pop("cause"),
            t=d.pop("t"),
            j=d.pop("j"),
            message=d.pop("message"),
            help=d.pop("help"),
            details=d,
        )

    def __str__(self) -> str:
        return self.message


class _Rows:
    """Rows ``rows`` of a states array ``x``, gathered only when read."""

    def __init__(self, x: np.ndarray, rows: np.ndarray):
        self.x = x
        self.rows = rows

    def __getitem__(self, mask: np.ndarray) -> "_Rows":
        return _Rows(self.x, self.rows[mask])

    def gather(self) -> np.ndarray:
        return self.x[self.rows]


class Jumps:
    """The jumps of a solution, one row per jump, in order.

    Attributes: ``rule`` (rule index), ``rule_name`` (array of names),
    ``t`` and ``j`` (the pre-jump hybrid time; the post-jump point is
    ``(t, j + 1)``), ``pre`` and ``post`` (``(k, n)`` arrays of states).
    """

    def __init__(
        self,
        rule: np.ndarray,
        t: np.ndarray,
        j: np.ndarray,
        pre: Union[np.ndarray, "_Rows"],
        post: Union[np.ndarray, "_Rows"],
        rule_names: Sequence[str],
        names: Sequence[str],
    ):
        self.rule = rule
        self.t = t
        self.j = j
        # Either arrays, or rows of the solution's `x` gathered on first use:
        # a run's jump states are its pre- and post-jump samples, so they are
        # not copied unless asked for.
        self._pre = pre
        self._post = post
        self.rule_names = list(rule_names)
        self.names = list(names)

    @property
    def pre(self) -> np.ndarray:
        """The pre-jump states, ``(k, n)``."""
        if isinstance(self._pre, _Rows):
            self._pre = self._pre.gather()
        return self._pre

    @property
    def post(self) -> np.ndarray:
        """The post-jump states, ``(k, n)``."""
        if isinstance(self._post, _Rows):
            self._post = self._post.gather()
        return self._post

    @property
    def rule_name(self) -> np.ndarray:
        """The rule names of the jumps, as an array of str."""
        names = np.asarray(self.rule_names if self.rule_names else [""], dtype=object)
        return names[self.rule.astype(np.intp)] if len(self.rule) else np.array([], dtype=object)

    def __len__(self) -> int:
        return len(self.t)

    def _select(self, mask: np.ndarray) -> "Jumps":
        return Jumps(
            self.rule[mask],
            self.t[mask],
            self.j[mask],
            self._pre[mask],
            self._post[mask],
            self.rule_names,
            self.names,
        )

    def to_pandas(self):
        """The table as a pandas DataFrame: ``rule``, ``t``, ``j``, then
        ``pre.<name>`` and ``post.<name>`` per state component."""
        import pandas as pd

        cols: Dict[str, Any] = {"rule": self.rule_name, "t": self.t, "j": self.j}
        for k, n in enumerate(self.names):
            cols[f"pre.{n}"] = self.pre[:, k]
        for k, n in enumerate(self.names):
            cols[f"post.{n}"] = self.post[:, k]
        return pd.DataFrame(cols)

    def __repr__(self) -> str:
        return f"<hybsim.Jumps: {len(self)} jumps>"


class Solution:
    """A simulated solution (returned by :meth:`hybsim.Model.run`).

    Attributes
    ----------
    t : ndarray (n,)
        Ordinary time of each sample.
    j : ndarray (n,) of int64
        Jump count of each sample.
    x : ndarray (n, d)
        States, one column per scalar component, named by ``names``: the
        states the model declares, in the order of ``hybsim run --csv``
        (not the timers the language adds for ``every`` and held ``noise``).
    y : ndarray (n, m)
        Outputs (the model's ``output`` declarations), named by
        ``output_names``.
    kind_code : ndarray (n,) of uint8
        Index into :data:`SAMPLE_KINDS` per sample; ``kind`` gives the words.
    jumps : Jumps
        One row per jump: rule, t, j, pre, post.
    termination : Termination or None
        Where and why the solution ended.
    solver_switches : list of dict
        Under ``solver="auto"``: each change of integrator, in order, as
        ``{"t", "j", "to"}`` (``to``: ``"radau5"`` where the flow became
        stiff, ``"dopri5"`` where it no longer is); empty otherwise.

    ``sol["h"]`` is the column of state (or output) component ``h``;
    ``len(sol)`` the number of samples.
    """

    def __init__(self, data: Dict[str, Any]):
        self.model: str = data["model"]
        self.seed: int = data["seed"]
        self.t: np.ndarray = data["t"]
        self.j: np.ndarray = data["j"]
        self.kind_code: np.ndarray = data["kind"]
        self.x: np.ndarray = data["x"]
        self._y: Optional[np.ndarray] = data.get("y")
        self._output_map = data.get("outputs")
        self.names: List[str] = list(data["names"])
        self.output_names: List[str] = list(data["output_names"])
        self.rule_names: List[str] = list(data["rule_names"])
        # Indices into `output_names` of the CSV's columns, in its order (`x` is in that order).
        self._output_columns: List[int] = list(
            data.get("output_columns", range(len(self.output_names)))
        )
        self.parameters: Dict[str, Any] = data.get("parameters", {})
        self.solver_switches: List[Dict[str, Any]] = list(data.get("solver_switches", []))
        jumps = data["jumps"]
        if isinstance(jumps, Jumps):
            self.jumps = jumps
        else:
            self.jumps = Jumps(
                jumps["rule"],
                jumps["t"],
                jumps["j"],
                *(
                    (jumps["pre"], jumps["post"])
                    if "pre" in jumps
                    else (_Rows(self.x, jumps["row"]), _Rows(self.x, jumps["row"] + 1))
                ),
                self.rule_names,
                self.names,
            )
        term = data["termination"]
        self.termination: Optional[Termination] = (
            term if isinstance(term, Termination) or term is None else Termination._from_dict(term)
        )
        self._columns = {n: ("x", k) for k, n in enumerate(self.names)}
        for k, n in enumerate(self.output_names):
            self._columns.setdefault(n, ("y", k))

    # -- access ---------------------------------------------------------------

    @property
    def y(self) -> np.ndarray:
        """The outputs, ``(n, m)``, one column per ``output_names`` entry:
        evaluated from ``t`` and ``x`` on first use (a run whose outputs are
        never read does not pay for them), then kept."""
        if self._y is None:
            if self._output_map is None or not self.output_names:
                self._y = np.empty((len(self.t), 0))
            else:
                self._y = self._output_map(self.t, self.x, self.j)
        return self._y

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, name: str) -> np.ndarray:
        """The column of state or output component ``name`` (``"h"``,
        ``"x[2]"``, ``"P[1,2]"``); for a vector or matrix state ``"x"``, its
        columns ``x[1]``, ``x[2]``, … as an ``(n, k)`` array."""
        if not isinstance(name, str):
            raise TypeError(
                f"a solution is indexed by a component's name (str), not "
                f"{type(name).__name__}; columns by position are sol.x[:, k]"
            )
        where = self._columns.get(name)
        if where is not None:
            arr, k = where
            return getattr(self, arr)[:, k]
        prefix = name + "["
        ks = [k for k, n in enumerate(self.names) if n.startswith(prefix)]
        if ks:
            return self.x[:, ks]
        ks = [k for k, n in enumerate(self.output_names) if n.startswith(prefix)]
        if ks:
            return self.y[:, ks]
        raise KeyError(
            f"no state or output `{name}`; the states are {', '.join(self.names) or 'none'}"
            + (f" and the outputs {', '.join(self.output_names)}" if self.output_names else "")
        )

    def __contains__(self, name: str) -> bool:
        try:
            self[name]
        except KeyError:
            return False
        return True

    @property
    def kind(self) -> np.ndarray:
        """The sample kinds as words (``initial``, ``flow``, ``pre_jump``,
        ``post_jump``, ``final``)."""
        return np.asarray(SAMPLE_KINDS)[self.kind_code]

    @property
    def end(self) -> tuple:
        """The last hybrid time ``(t, j)``, or None for an empty solution."""
        if len(self) == 0:
            return None
        return (float(self.t[-1]), int(self.j[-1]))

    def __repr__(self) -> str:
        end = self.end
        where = f"ended at t = {end[0]:g}, j = {end[1]}" if end else "empty"
        why = f" ({self.termination.cause})" if self.termination else ""
        return (
            f"<hybsim.Solution of {self.model}: {len(self)} samples, "
            f"{len(self.jumps)} jumps, {where}{why}>"
        )

    # -- tables ---------------------------------------------------------------

    def _table(self) -> Dict[str, Any]:
        cols: Dict[str, Any] = {"t": self.t, "j": self.j, "kind": self.kind}
        for k, n in enumerate(self.names):
            cols[n] = self.x[:, k]
        for k in self._output_columns:
            n = self.output_names[k]
            if n not in cols:
                cols[n] = self.y[:, k]
        return cols

    def to_pandas(self):
        """The samples as a pandas DataFrame with the columns of ``hybsim run
        --csv``: ``t``, ``j``, ``kind``, the states, the outputs."""
        try:
            import pandas as pd
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("to_pandas() needs pandas: pip install pandas") from e
        return pd.DataFrame(self._table())

    def to_polars(self):
        """The samples as a polars DataFrame (columns as :meth:`to_pandas`)."""
        try:
            import polars as pl
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("to_polars() needs polars: pip install polars") from e
        table = self._table()
        table["kind"] = table["kind"].astype(str)
        return pl.DataFrame(table)

    # -- HybridArc helpers ----------------------------------------------------

    def _subset(self, mask: np.ndarray, jump_mask: np.ndarray) -> "Solution":
        return Solution(
            {
                "model": self.model,
                "seed": self.seed,
                "t": self.t[mask],
                "j": self.j[mask],
                "kind": self.kind_code[mask],
                "x": self.x[mask],
                "y": None if self._y is None else self._y[mask],
                "outputs": self._output_map,
                "names": self.names,
                "output_names": self.output_names,
                "output_columns": self._output_columns,
                "rule_names": self.rule_names,
                "parameters": self.parameters,
                "jumps": self.jumps._select(jump_mask),
                "termination": self.termination,
                "solver_switches": self.solver_switches,
            }
        )

    def restrict_t(self, t_min: Optional[float] = None, t_max: Optional[float] = None) -> "Solution":
        """The samples with ``t_min <= t <= t_max`` (either bound may be
        None) and the jumps at those times, as a new Solution (HyEQ's
        ``restrictT``). ValueError for ``t_min > t_max`` or a NaN bound
        (no sample would be kept)."""
        lo, hi = _interval("t", t_min, t_max, -np.inf, np.inf)
        return self._subset(
            (self.t >= lo) & (self.t <= hi), (self.jumps.t >= lo) & (self.jumps.t <= hi)
        )

    def restrict_j(self, j_min: Optional[int] = None, j_max: Optional[int] = None) -> "Solution":
        """The samples with ``j_min <= j <= j_max`` (either bound may be
        None) and the jumps between them (from ``(t, j)`` to ``(t, j + 1)``
        with both ends inside), as a new Solution (HyEQ's ``restrictJ``).
        ValueError for ``j_min > j_max``."""
        lo, hi = _interval("j", j_min, j_max, np.iinfo(np.int64).min, np.iinfo(np.int64).max)
        return self._subset(
            (self.j >= lo) & (self.j <= hi), (self.jumps.j >= lo) & (self.jumps.j + 1 <= hi)
        )

    def interpolate(self, t_grid: Union[Sequence[float], np.ndarray], at_jump: str = "start") -> "Solution":
        """The solution at the ordinary times ``t_grid`` (nondecreasing),
        linearly interpolated between the two samples of a flow interval
        around each time (as the Rust ``HybridArc::value_at``; exact at
        samples).

        At a jump time the solution has several values (one per flow
        interval containing ``t``): ``at_jump`` picks ``"start"`` (the
        first, before the jumps), ``"end"`` (the last, after them),
        ``"both"`` (a row for each of the two, so ``t`` repeats) or
        ``"nan"`` (NaN). Times outside ``[t[0], t[-1]]`` give NaN states
        and ``j = -1``. Returns a Solution whose samples are the grid
        points (kind ``flow``) and whose jumps are those in the grid's
        range.
        """
        if at_jump not in _AT_JUMP:
            raise ValueError(f"at_jump={at_jump!r}: use one of {', '.join(map(repr, _AT_JUMP))}")
        tau = np.asarray(t_grid, dtype=np.float64).reshape(-1)
        # A NaN passes the order test and gave a row at no time.
        if np.isnan(tau).any():
            raise ValueError("t_grid holds NaN: every time must be a number")
        if tau.size > 1 and np.any(np.diff(tau) < 0):
            raise ValueError("t_grid must be nondecreasing")
        n = len(self.t)
        if n == 0:
            raise ValueError("cannot interpolate an empty solution")
        inside = (tau >= self.t[0]) & (tau <= self.t[-1])
        # First sample with t >= tau lies in the first flow interval containing
        # tau; the last sample with t <= tau in the last one (t is nondecreasing
        # along the whole domain).
        first = np.clip(np.searchsorted(self.t, tau, side="left"), 0, n - 1)
        last = np.clip(np.searchsorted(self.t, tau, side="right") - 1, 0, n - 1)
        several = inside & (self.j[first] != self.j[last])

        def value(b: np.ndarray, a: np.ndarray, arr: np.ndarray) -> np.ndarray:
            # Linear between samples a <= b of one interval; exact where t == tau.
            ta, tb = self.t[a], self.t[b]
            span = tb - ta
            w = np.divide(tau - ta, span, out=np.zeros_like(tau), where=span > 0)
            va, vb = arr[a], arr[b]
            out = va + w[:, None] * (vb - va)
            exact_b = self.t[b] == tau
            out[exact_b] = vb[exact_b]
            exact_a = (self.t[a] == tau) & ~exact_b
            out[exact_a] = va[exact_a]
            return out

        # "start": interval of `first`, bracket [first - 1, first].
        a_s = np.maximum(first - 1, 0)
        a_s = np.where(self.j[a_s] == self.j[first], a_s, first)
        # "end": interval of `last`, bracket [last, last + 1].
        b_e = np.minimum(last + 1, n - 1)
        b_e = np.where(self.j[b_e] == self.j[last], b_e, last)
        xs, ys = value(first, a_s, self.x), value(first, a_s, self.y)
        xe, ye = value(b_e, last, self.x), value(b_e, last, self.y)
        js, je = self.j[first], self.j[last]

        if at_jump == "both":
            reps = np.where(several, 2, 1)
            t_out = np.repeat(tau, reps)
            pos = np.cumsum(reps) - reps  # row of each grid point's first value
            x = np.repeat(xs, reps, axis=0)
            y = np.repeat(ys, reps, axis=0)
            j = np.repeat(js, reps)
            second = pos[several] + 1
            x[second], y[second], j[second] = xe[several], ye[several], je[several]
            keep_nan = np.repeat(~inside, reps)
        else:
            t_out = tau
            if at_jump == "end":
                x, y, j = xe, ye, je.copy()
            else:
                x, y, j = xs, ys, js.copy()
                if at_jump == "nan":
                    x, y = x.copy(), y.copy()
                    x[several] = np.nan
                    y[several] = np.nan
            keep_nan = ~inside
        x = np.array(x, dtype=np.float64)
        y = np.array(y, dtype=np.float64)
        j = np.array(j, dtype=np.int64)
        x[keep_nan] = np.nan
        y[keep_nan] = np.nan
        j[keep_nan] = -1
        lo, hi = (tau[0], tau[-1]) if tau.size else (0.0, -1.0)
        return Solution(
            {
                "model": self.model,
                "seed": self.seed,
                "t": t_out,
                "j": j,
                "kind": np.full(len(t_out), SAMPLE_KINDS.index("flow"), dtype=np.uint8),
                "x": x,
                "y": y,
                "outputs": self._output_map,
                "names": self.names,
                "output_names": self.output_names,
                "output_columns": self._output_columns,
                "rule_names": self.rule_names,
                "parameters": self.parameters,
                "jumps": self.jumps._select((self.jumps.t >= lo) & (self.jumps.t <= hi)),
                "termination": self.termination,
                "solver_switches": self.solver_switches,
            }
        )
