"""Plots of hybrid solutions with the HyEQ Toolbox's conventions (needs
matplotlib): flows as solid lines, one line per flow interval (never drawn
across a jump); jumps as dashed lines from the pre-jump to the post-jump
value, with a marker at each end (``.`` at the start, ``*`` at the end).

- :func:`flows`: components against ordinary time t (HyEQ ``plotFlows``);
- :func:`jumps`: components against the jump count j (``plotJumps``);
- :func:`hybrid`: one component over the hybrid time domain (t, j) in 3-D
  (``plotHybrid``);
- :func:`phase`: one component against another (``plotPhase``).

Each draws into ``ax`` (or a new figure) and returns the axes. Every
solution is drawn with a fixed number of matplotlib artists, whatever its
number of jumps (intervals are separated by NaN rows).
"""

from __future__ import annotations

from typing import Any, List, Optional, Sequence, Union

import numpy as np

from .solution import Solution

#: Line style of jumps and the markers of their two ends (HyEQ defaults).
JUMP_STYLE = {"linestyle": "--", "linewidth": 0.8}
JUMP_START_MARKER = "."
JUMP_END_MARKER = "*"


def _pyplot():
    try:
        import matplotlib.pyplot as plt
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("hybsim.plot needs matplotlib: pip install matplotlib") from e
    return plt


def _names(sol: Solution, names: Union[None, str, Sequence[str]]) -> List[str]:
    if names is None:
        return list(sol.names)
    if isinstance(names, str):
        names = [names]
    out: List[str] = []
    for n in names:
        col = sol[n]  # KeyError names the components
        if col.ndim == 2:
            prefix = n + "["
            out += [m for m in sol.names + sol.output_names if m.startswith(prefix)]
        else:
            out.append(n)
    return out


def _jump_values(sol: Solution, name: str):
    """The pre- and post-jump values of component `name` (outputs: read from
    the pre- and post-jump samples)."""
    if name in sol.names:
        k = sol.names.index(name)
        return sol.jumps.pre[:, k], sol.jumps.post[:, k]
    kind = sol.kind_code
    col = sol[name]
    pre = col[kind == 2]
    post = col[kind == 3]
    m = min(len(pre), len(post), len(sol.jumps))
    return pre[:m], post[:m]


def _broken(keys: np.ndarray, *cols: np.ndarray):
    """`cols` with a NaN row inserted wherever `keys` (the jump count)
    changes, so that one line never joins two flow intervals."""
    cut = np.flatnonzero(np.diff(keys)) + 1
    return [np.insert(np.asarray(c, dtype=np.float64), cut, np.nan) for c in cols]


def _segments(*pairs: np.ndarray):
    """Rows (a0, b0, NaN, a1, b1, NaN, ...) for each coordinate pair (a, b)."""
    out = []
    for a, b in pairs:
        k = len(a)
        seg = np.empty(3 * k)
        seg[0::3], seg[1::3], seg[2::3] = a, b, np.nan
        out.append(seg)
    return out


def _draw_jumps(ax, color, xs, ys, zs=None, label_markers=True):
    if len(xs[0]) == 0:
        return
    if zs is None:
        sx, sy = _segments(xs, ys)
        ax.plot(sx, sy, color=color, **JUMP_STYLE)
        if label_markers:
            ax.plot(xs[0], ys[0], JUMP_START_MARKER, color=color)
            ax.plot(xs[1], ys[1], JUMP_END_MARKER, color=color, markersize=5)
    else:
        sx, sy, sz = _segments(xs, ys, zs)
        ax.plot(sx, sy, sz, color=color, **JUMP_STYLE)
        if label_markers:
            ax.plot(xs[0], ys[0], zs[0], JUMP_START_MARKER, color=color)
            ax.plot(xs[1], ys[1], zs[1], JUMP_END_MARKER, color=color, markersize=5)


def _axes(ax, n: int, sharex: bool = True, projection: Optional[str] = None):
    plt = _pyplot()
    if ax is not None:
        return list(np.atleast_1d(ax))
    if projection is not None:
        fig = plt.figure()
        return [fig.add_subplot(1, 1, 1, projection=projection)]
    fig, axes = plt.subplots(n, 1, sharex=sharex, squeeze=False, figsize=(6.4, 1.2 + 1.6 * n))
    return list(axes[:, 0])


def flows(
    sol: Solution,
    names: Union[None, str, Sequence[str]] = None,
    ax: Any = None,
    jumps: bool = True,
    **line: Any,
):
    """Components ``names`` (default: every state component) against t, one
    subplot each (or all into ``ax`` if one axes is given), with the jumps
    as dashed vertical lines. Extra keywords go to the flow lines."""
    names = _names(sol, names)
    axes = _axes(ax, len(names))
    for i, name in enumerate(names):
        a = axes[i] if len(axes) > 1 else axes[0]
        t, v = _broken(sol.j, sol.t, sol[name])
        (ln,) = a.plot(t, v, label=name, **line)
        if jumps:
            pre, post = _jump_values(sol, name)
            tj = sol.jumps.t[: len(pre)]
            _draw_jumps(a, ln.get_color(), (tj, tj), (pre, post))
        a.set_ylabel(name)
    axes[-1].set_xlabel("t")
    return axes[0] if len(axes) == 1 else axes


def jumps(
    sol: Solution,
    names: Union[None, str, Sequence[str]] = None,
    ax: Any = None,
    **line: Any,
):
    """Components ``names`` against the jump count j (HyEQ ``plotJumps``):
    each flow interval collapses to a vertical solid line at its j, each
    jump is a dashed line from (j, pre) to (j + 1, post)."""
    names = _names(sol, names)
    axes = _axes(ax, len(names))
    for i, name in enumerate(names):
        a = axes[i] if len(axes) > 1 else axes[0]
        jj, v = _broken(sol.j, sol.j.astype(np.float64), sol[name])
        (ln,) = a.plot(jj, v, label=name, **line)
        pre, post = _jump_values(sol, name)
        k = len(pre)
        jt = sol.jumps.j[:k].astype(np.float64)
        _draw_jumps(a, ln.get_color(), (jt, jt + 1), (pre, post))
        a.set_ylabel(name)
    axes[-1].set_xlabel("j")
    return axes[0] if len(axes) == 1 else axes


def hybrid(sol: Solution, name: Optional[str] = None, ax: Any = None, **line: Any):
    """Component ``name`` (default: the first state component) over the
    hybrid time domain: a 3-D plot with axes t, j and the value (HyEQ
    ``plotHybrid``)."""
    name = name if name is not None else sol.names[0]
    (a,) = _axes(ax, 1, projection="3d")
    t, jj, v = _broken(sol.j, sol.t, sol.j.astype(np.float64), sol[name])
    (ln,) = a.plot(t, jj, v, label=name, **line)
    pre, post = _jump_values(sol, name)
    k = len(pre)
    jt = sol.jumps.j[:k].astype(np.float64)
    tt = sol.jumps.t[:k]
    _draw_jumps(a, ln.get_color(), (tt, tt), (jt, jt + 1), (pre, post))
    a.set_xlabel("t")
    a.set_ylabel("j")
    a.set_zlabel(name)
    return a


def phase(sol: Solution, x: Optional[str] = None, y: Optional[str] = None, ax: Any = None, **line: Any):
    """Component ``y`` against component ``x`` (default: the first two
    state components; HyEQ ``plotPhase``), flows solid, jumps dashed from
    the pre-jump to the post-jump point. ``phase(sol, ["h", "v"])``, two
    names as ``--plot-vars`` gives them, is ``phase(sol, "h", "v")``."""
    if isinstance(x, (list, tuple)) and y is None:
        # The pair as one argument was "a solution is indexed by a component's name".
        if len(x) != 2:
            raise ValueError(f"phase() draws two components, got {len(x)}: {list(x)}")
        x, y = x
    for name in (x, y):
        if name is not None and not isinstance(name, str):
            raise TypeError(f"phase(): components are named by str, not {type(name).__name__}")
    if x is None or y is None:
        if len(sol.names) < 2:
            raise ValueError("phase() needs two components: pass x= and y=")
        x = x if x is not None else sol.names[0]
        y = y if y is not None else sol.names[1]
    (a,) = _axes(ax, 1)
    u, v = _broken(sol.j, sol[x], sol[y])
    (ln,) = a.plot(u, v, **line)
    xp, xq = _jump_values(sol, x)
    yp, yq = _jump_values(sol, y)
    k = min(len(xp), len(yp))
    _draw_jumps(a, ln.get_color(), (xp[:k], xq[:k]), (yp[:k], yq[:k]))
    a.set_xlabel(x)
    a.set_ylabel(y)
    return a
