"""Compiled loops (numba) for the env's resets and steps and the observers' kept maps.

Why compiled: a reset with walls needs a BFS and a wall-crossing count per layout, a step
touches a few cells per env, and an ODMTL observation writes every agent's windows; as numpy
array programs these were ~10 passes over (B, C) arrays each, which kept the Ch. 4 preset at
~350k agent-steps/s (issue 10 asks for 1M; it is 1.1M now). As loops they touch each cell
once. Every kernel computes the same numbers as the numpy formulas it replaced (integers
exactly; floats in the same order of operations, float32 where the numpy code was float32;
``exp`` and ``log1p`` stay numpy's), so the env is bit-identical to them; the cell-by-cell
references in tests/mdrl/test_env.py and test_observations.py check that.

Single-threaded: a worker process is one core's job, and the batch already amortises the
Python overhead. ``cache=True`` compiles once per machine (~5 s) into ``__pycache__`` (or
``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# ---------------------------------------------------------------------------- env reset


@njit(cache=True, nogil=True, error_model="numpy")
def walls_bfs(target, walls, rows, cols, moves, unreachable):  # pragma: no cover - compiled
    """(k, C) int32 BFS steps to ``target`` over the walls (k, C) bool; a cell that cannot be
    reached (a wall, a walled-off pocket) gets ``unreachable``: ``walking_steps`` with one
    source cell per layout."""
    return walking_steps(target.reshape(-1, 1), walls, rows, cols, moves, unreachable)[:, 0]


@njit(cache=True, nogil=True, error_model="numpy")
def walking_steps(sources, walls, rows, cols, moves, unreachable):  # pragma: no cover
    """(R, k, C) int32 BFS steps from each of ``sources`` (R, k) over layout r's walls (R, C)
    bool; ``unreachable`` where no path goes (a wall, a walled-off pocket). A move enters a
    free cell; a diagonal (dr, dc) also needs both orthogonal cells beside it free (no corner
    cutting), so moves are symmetric and steps from a source are steps to it; a source in a
    wall reaches nothing. The search runs on the grid with a border of walls, where every move
    is an index offset; a layout's grid is built once for its k searches."""
    count, k = sources.shape
    cells = walls.shape[1]
    width = cols + 2
    dist = np.full((count, k, cells), unreachable, dtype=np.int32)
    free = np.zeros((rows + 2) * width, dtype=np.bool_)
    seen = np.empty((rows + 2) * width, dtype=np.int32)
    queue = np.empty(cells, dtype=np.int64)
    step = np.empty(moves.shape[0], dtype=np.int64)  # offsets of the moves and their sides
    side_r = np.empty(moves.shape[0], dtype=np.int64)
    side_c = np.empty(moves.shape[0], dtype=np.int64)
    for a in range(moves.shape[0]):
        step[a] = moves[a, 0] * width + moves[a, 1]
        diagonal = moves[a, 0] != 0 and moves[a, 1] != 0
        side_r[a] = moves[a, 0] * width if diagonal else 0
        side_c[a] = moves[a, 1] if diagonal else 0
    for e in range(count):
        for r in range(rows):
            for c in range(cols):
                free[(r + 1) * width + c + 1] = not walls[e, r * cols + c]
        for j in range(k):
            t = sources[e, j]
            start = (t // cols + 1) * width + t % cols + 1
            if not free[start]:
                continue  # nobody stands in a wall: no path from one
            seen[:] = -1
            seen[start] = 0
            queue[0] = start
            head, tail = 0, 1
            while head < tail:
                x = queue[head]
                head += 1
                for a in range(1, moves.shape[0]):
                    y = x + step[a]
                    if free[y] and seen[y] < 0 and free[x + side_r[a]] and free[x + side_c[a]]:
                        seen[y] = seen[x] + 1
                        queue[tail] = y
                        tail += 1
            for r in range(rows):
                for c in range(cols):
                    d = seen[(r + 1) * width + c + 1]
                    if d >= 0:
                        dist[e, j, r * cols + c] = d
    return dist


@njit(cache=True, nogil=True, inline="always")
def _run(grid, start, step, count):  # pragma: no cover - compiled
    """Wall cells in a row from ``start`` on, ``step`` apart, at most ``count``."""
    k = 0
    while k < count and grid[start + k * step]:
        k += 1
    return k


@njit(cache=True, nogil=True, error_model="numpy")
def _runs(grid, rows, cols):  # pragma: no cover - compiled
    """Run lengths of wall cells from each side: top/bottom per column, left/right per row."""
    top = np.zeros(cols, dtype=np.int64)
    bottom = np.zeros(cols, dtype=np.int64)
    left = np.zeros(rows, dtype=np.int64)
    right = np.zeros(rows, dtype=np.int64)
    for c in range(cols):
        top[c] = _run(grid, c, cols, rows)
        bottom[c] = _run(grid, (rows - 1) * cols + c, -cols, rows)
    for r in range(rows):
        left[r] = _run(grid, r * cols, 1, cols)
        right[r] = _run(grid, r * cols + cols - 1, -1, cols)
    return top, bottom, left, right


@njit(cache=True, nogil=True, error_model="numpy")
def _slab_counts(count, q_a, q_s, centre, a_axis, near, far, size_a, size_s, span, rows, cols):
    """Add to ``count`` (C,) the slabs of one orientation that each detector-source line
    crosses. Slab ``line`` lies at a = (line + 0.5) * size_a, a cell centre line; the lines to
    a source on the other side of it cross it, where the crossing point s (along the slab)
    lies on the wall run from the near side (s <= near * size_s) or from the far side
    (s >= (span - far) * size_s). ``a_axis`` 1: slabs on column lines (a = x), 0: row lines.
    """  # pragma: no cover - compiled
    lines = cols if a_axis == 1 else rows
    others = rows if a_axis == 1 else cols
    for line in range(lines):
        if near[line] == 0 and far[line] == 0:
            continue
        aw = (line + 0.5) * size_a
        dq = q_a - aw
        if dq == 0:  # the source on the line: no detector line crosses it
            continue
        lo, hi = (0, line) if dq > 0 else (line + 1, lines)  # detectors with dp * dq < 0
        for k in range(lo, hi):
            for o in range(others):
                p = o * cols + k if a_axis == 1 else k * cols + o
                if _crosses(centre[p, a_axis], centre[p, 1 - a_axis], q_a, q_s, aw, dq,
                            near[line], far[line], size_s, span):
                    count[p] += 1


@njit(cache=True, nogil=True, inline="always")
def _crosses(a_p, s_p, q_a, q_s, aw, dq, near, far, size_s, span):  # pragma: no cover - compiled
    """Whether the line from the detector (a_p, s_p) to the source (q_a, q_s), on the other
    side of the slab line a = aw (dq = q_a - aw), crosses it on the wall run from the near or
    the far side (``_slab_counts``)."""
    dp = a_p - aw
    s = s_p + dp / (dp - dq) * (q_s - s_p)
    return (near > 0 and s <= near * size_s) or (far > 0 and s >= (span - far) * size_s)


@njit(cache=True, nogil=True, error_model="numpy")
def wall_slant(target, walls, centre, slant_x, slant_y, slant_row, rows, cols, size_y, size_x):
    """(R, C) float64 sum of 1 / cos(theta) over the wall slabs that each detector-source line
    crosses (``TargetLocalizationEnv._transmission``): per orientation, the slant of that
    orientation added once per slab crossed, from 0.0, one term at a time; then the two sums
    added. ``slant_x``/``slant_y`` (S, C): the detector-source length over |dx| and |dy|, for
    the source of layout e in row ``slant_row[e]``.
    """  # pragma: no cover - compiled
    count, cells = walls.shape
    out = np.zeros((count, cells))
    along = np.empty(cells, dtype=np.int64)
    across = np.empty(cells, dtype=np.int64)
    for e in range(count):
        top, bottom, left, right = _runs(walls[e], rows, cols)
        qy, qx = centre[target[e], 0], centre[target[e], 1]
        along[:] = 0
        across[:] = 0
        # slabs on column centre lines (walls from the top or bottom), then on row lines
        _slab_counts(along, qx, qy, centre, 1, top, bottom, size_x, size_y, rows, rows, cols)
        _slab_counts(across, qy, qx, centre, 0, left, right, size_y, size_x, cols, rows, cols)
        sx, sy = slant_x[slant_row[e]], slant_y[slant_row[e]]
        for p in range(cells):
            x = 0.0
            for _ in range(along[p]):
                x += sx[p]
            y = 0.0
            for _ in range(across[p]):
                y += sy[p]
            out[e, p] = x + y
    return out


@njit(cache=True, nogil=True, inline="always")
def _line_crossings(k, a_p, s_p, q_a, q_s, lines, near, far, size_a, size_s, span):
    """Slabs of one orientation (on ``lines``) that the line from the detector (index k along
    the a axis, at (a_p, s_p)) to the source (q_a, q_s) crosses."""  # pragma: no cover
    n = 0
    for line in lines:
        aw = (line + 0.5) * size_a
        dq = q_a - aw
        if ((dq > 0 and k < line) or (dq < 0 and k > line)) and _crosses(
                a_p, s_p, q_a, q_s, aw, dq, near[line], far[line], size_s, span):
            n += 1
    return n


@njit(cache=True, nogil=True, inline="always")
def _pair_slant(p, q, centre, sx, sy, col_lines, row_lines, top, bottom, left, right, rows,
                cols, size_y, size_x):  # pragma: no cover - compiled
    """``wall_slant``'s value for the detector at cell p and the source at cell q, bit for bit
    (same crossing test, same sums), looking only at the lines that hold a wall. ``sx``/``sy``:
    the pair's length over |dx| and |dy|."""
    py, px = centre[p, 0], centre[p, 1]
    qy, qx = centre[q, 0], centre[q, 1]
    pr, pc = p // cols, p % cols
    # slabs on column lines (a = x), as _slab_counts(axis 1), then on row lines (a = y)
    along = _line_crossings(pc, px, py, qx, qy, col_lines, top, bottom, size_x, size_y, rows)
    across = _line_crossings(pr, py, px, qy, qx, row_lines, left, right, size_y, size_x, cols)
    x = 0.0
    for _ in range(along):
        x += sx
    y = 0.0
    for _ in range(across):
        y += sy
    return x + y


@njit(cache=True, nogil=True, error_model="numpy")
def slant_at(cells, walls, centre, slant_x, slant_y, slant_row, rows, cols, size_y, size_x):
    """(R, C) float64: for the detector at ``cells[r]`` under layout ``walls[r]`` and every
    source c, ``wall_slant``'s value of that pair: a column of the env's unit counts.
    ``slant_x``/``slant_y`` (S, C): row ``slant_row[r]`` holds the pairs' length over |dx| and
    |dy| for detector r and each source (the env's tables are symmetric).
    """  # pragma: no cover - compiled
    count, n_cells = walls.shape
    out = np.zeros((count, n_cells))
    for r in range(count):
        top, bottom, left, right = _runs(walls[r], rows, cols)
        col_lines = np.flatnonzero((top > 0) | (bottom > 0))  # the few lines with a wall
        row_lines = np.flatnonzero((left > 0) | (right > 0))
        sx, sy = slant_x[slant_row[r]], slant_y[slant_row[r]]
        for c in range(n_cells):
            out[r, c] = _pair_slant(cells[r], c, centre, sx[c], sy[c], col_lines, row_lines, top,
                                    bottom, left, right, rows, cols, size_y, size_x)
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def belief_add(sum_log, sum_gain, envs, cells, d_reading, d_visits, walls, free_gain,
               log_free_gain, mu_t, centre, slant_x, slant_y, slant_row, rows, cols, size_y,
               size_x, log_floor):
    """The belief filter's update (belief.py) for new readings: for each (env, cell x) r,
    ``sum_log[e, c] += d_reading[r] * max(log g(c, x), log_floor)`` and ``sum_gain[e, c] +=
    d_visits[r] * g(c, x)`` for every source c, with g the env's unit count: the free gain
    times exp(-mu t slant) (the slant of ``_pair_slant``), so log g = log free gain - mu t
    slant, no log per pair. One pass, no (R, C) temporaries.
    """  # pragma: no cover - compiled
    n_cells = walls.shape[1]
    for r in range(len(cells)):
        e, x = envs[r], cells[r]
        top, bottom, left, right = _runs(walls[e], rows, cols)
        col_lines = np.flatnonzero((top > 0) | (bottom > 0))
        row_lines = np.flatnonzero((left > 0) | (right > 0))
        walled = len(col_lines) + len(row_lines) > 0
        sx, sy = slant_x[slant_row[r]], slant_y[slant_row[r]]
        gain, log_gain = free_gain[x], log_free_gain[x]
        dr, dv = d_reading[r], d_visits[r]
        for c in range(n_cells):
            g, lg = gain[c], log_gain[c]
            if walled:
                slant = _pair_slant(x, c, centre, sx[c], sy[c], col_lines, row_lines, top,
                                    bottom, left, right, rows, cols, size_y, size_x)
                if slant > 0.0:
                    g = g * np.exp(-mu_t * slant)
                    lg = max(lg - mu_t * slant, log_floor)
            sum_log[e, c] += dr * lg
            sum_gain[e, c] += dv * g


@njit(cache=True, nogil=True)
def mark_wall_sets(walls, side, place, length):  # pragma: no cover - compiled
    """Set the cells of K walls per env in ``walls`` (R, m, n): wall k of env e leaves side
    ``side[e, k]`` (0 top, 1 bottom, 2 left, 3 right) at ``place[e, k]`` along it,
    ``length[e, k]`` cells deep (0: no wall)."""
    m, n = walls.shape[1], walls.shape[2]
    for e in range(walls.shape[0]):
        for k in range(side.shape[1]):
            s, q = side[e, k], place[e, k]
            for j in range(length[e, k]):
                if s == 0:
                    walls[e, j, q] = True
                elif s == 1:
                    walls[e, m - 1 - j, q] = True
                elif s == 2:
                    walls[e, q, j] = True
                else:
                    walls[e, q, n - 1 - j] = True


@njit(cache=True, nogil=True, inline="always")
def _allowed(w, rows, cols, r, c, dr, dc):  # pragma: no cover - compiled
    """The move rule (env module docstring): from (r, c) by (dr, dc) the move stays on the
    grid, enters a free cell and, a diagonal, has both orthogonal cells beside it free."""
    nr, nc = r + dr, c + dc
    return (
        0 <= nr < rows
        and 0 <= nc < cols
        and not w[nr * cols + nc]
        and (dr == 0 or dc == 0 or not (w[r * cols + nc] or w[nr * cols + c]))
    )


@njit(cache=True, nogil=True, error_model="numpy")
def valid_moves(walls, rows, cols, moves):  # pragma: no cover - compiled
    """bool (R, C, A): which moves ``_allowed`` allows from every cell of every layout."""
    count, cells = walls.shape
    out = np.empty((count, cells, moves.shape[0]), dtype=np.bool_)
    for e in range(count):
        for x in range(cells):
            for a in range(moves.shape[0]):
                out[e, x, a] = _allowed(
                    walls[e], rows, cols, x // cols, x % cols, moves[a, 0], moves[a, 1]
                )
    return out


# ---------------------------------------------------------------------------- ODMTL observer


@njit(cache=True, nogil=True, error_model="numpy")
def kept_cells(pos, new_r, new_v, readings, readings_top, track_top, visits, visits_top,
               ds_visits, rq_t, exact):  # pragma: no cover - compiled
    """Bring an observer's kept maps (``observations._Kept``) up to date at the agents' cells
    ``pos`` (B, N) after one step: the readings ``new_r`` and visits ``new_v`` (B, N) there.
    A cell shared with an earlier agent is done once. Row maxima follow (raised, or recomputed
    where the maximum fell); the fixed-point downsized visits get the change of each cell
    (integers, so exact in any order) while ``exact`` holds. -> whether it still holds."""
    b_count, n = pos.shape
    cells = readings.shape[1]
    if exact:
        for b in range(b_count):
            for i in range(n):
                v = new_v[b, i]
                if not (v == np.round(v) and 0 <= v <= 4096):  # observations.EXACT_COUNTS
                    exact = False
    for b in range(b_count):
        fell_r, fell_v = False, False
        for i in range(n):
            c = pos[b, i]
            seen = False
            for j in range(i):
                if pos[b, j] == c:
                    seen = True
            if seen:
                continue
            old, new = readings[b, c], new_r[b, i]
            readings[b, c] = new
            if track_top:
                if new > readings_top[b]:
                    readings_top[b] = new
                elif new < old and old >= readings_top[b]:
                    fell_r = True
            old, new = visits[b, c], new_v[b, i]
            visits[b, c] = new
            if new > visits_top[b]:
                visits_top[b] = new
            elif new < old and old >= visits_top[b]:
                fell_v = True
            if exact and new != old:
                change = np.float64(new) - np.float64(old)
                for k in range(ds_visits.shape[1]):
                    ds_visits[b, k] += rq_t[c, k] * change
        if fell_r:
            top = readings[b, 0]
            for c in range(1, cells):
                top = max(top, readings[b, c])
            readings_top[b] = top
        if fell_v:
            top = visits[b, 0]
            for c in range(1, cells):
                top = max(top, visits[b, c])
            visits_top[b] = top
    return exact


@njit(cache=True, nogil=True, error_model="numpy")
def odmtl_fill(actor, critic, pos, centre, rows, cols, w, readings, inv_r, ds_r, ds_v, inv_v,
               rt, walls, ds_w, others, walls_at, reduced_critic):  # pragma: no cover
    """Write the ODMTL stacks (``Observer._observe_odmtl``) from the kept maps, env by env.

    actor (B, N, C_a, w*w): windowed own location, windowed readings, downsized own location,
    [downsized others], downsized readings, downsized visits, and with walls (``walls_at`` >
    0, the channel of the windowed walls) the windowed walls, then the downsized walls when
    ``ds_w`` has rows. The reduced critic (B, C_c, w*w): downsized all locations, readings,
    visits, [walls]. Windows centre on ``centre`` (B, N) and read 0 off the grid. Every value
    is the float32 arithmetic of the numpy builder: maps x (1 / max), others clipped at 0 and
    divided by the largest count on another agent's cell, the agents' downsized locations
    summed in agent order.
    """
    b_count, n = pos.shape
    ww = w * w
    p = w // 2
    zero = np.float32(0.0)
    ds_all = np.empty(ww, dtype=np.float32)
    at_cell = np.empty(n, dtype=np.int64)
    for b in range(b_count):
        for k in range(ww):
            ds_all[k] = rt[pos[b, 0], k]
        for i in range(1, n):
            for k in range(ww):
                ds_all[k] += rt[pos[b, i], k]
        top_count = 0
        for i in range(n):
            count = 0
            for j in range(n):
                if pos[b, j] == pos[b, i]:
                    count += 1
            at_cell[i] = count
            top_count = max(top_count, count)
        ir, iv = inv_r[b], inv_v[b]
        for i in range(n):
            a = actor[b, i]
            cr, cc = centre[b, i] // cols, centre[b, i] % cols
            a[0, :] = zero
            dr, dc = pos[b, i] // cols - cr + p, pos[b, i] % cols - cc + p
            if 0 <= dr < w and 0 <= dc < w:
                a[0, dr * w + dc] = np.float32(1.0)
            # windows: the grid cells they cover, 0 off the grid
            full = cc - p >= 0 and cc - p + w <= cols and cr - p >= 0 and cr - p + w <= rows
            if not full:
                a[1, :] = zero
                if walls_at > 0:
                    a[walls_at, :] = zero
            c0, c1 = max(cc - p, 0), min(cc - p + w, cols)
            for r in range(max(cr - p, 0), min(cr - p + w, rows)):
                at = (r - cr + p) * w - (cc - p)  # window element of cell (r, c): at + c
                if walls_at > 0:  # one loop for both windows: the loops are short
                    for c in range(c0, c1):
                        a[1, at + c] = readings[b, r * cols + c] * ir
                        a[walls_at, at + c] = np.float32(walls[b, r * cols + c])
                else:
                    for c in range(c0, c1):
                        a[1, at + c] = readings[b, r * cols + c] * ir
            for k in range(ww):
                a[2, k] = rt[pos[b, i], k]
            ch = 3
            if others:
                top = 1
                for j in range(n):
                    if j != i:
                        top = max(top, at_cell[j] - (1 if pos[b, j] == pos[b, i] else 0))
                denominator = np.float32(top)
                for k in range(ww):
                    a[3, k] = max(ds_all[k] - a[2, k], zero) / denominator
                ch = 4
            # one channel at a time: a loop over k writing several channels runs ~2x slower
            for k in range(ww):
                a[ch, k] = ds_r[b, k] * ir
            for k in range(ww):
                a[ch + 1, k] = ds_v[b, k] * iv
            if walls_at > 0 and len(ds_w):
                for k in range(ww):
                    a[walls_at + 1, k] = ds_w[b, k]
        if reduced_critic:
            cnt = np.float32(top_count)
            for k in range(ww):
                critic[b, 0, k] = ds_all[k] / cnt
            for k in range(ww):
                critic[b, 1, k] = ds_r[b, k] * ir
            for k in range(ww):
                critic[b, 2, k] = ds_v[b, k] * iv
            if walls_at > 0 and len(ds_w):
                for k in range(ww):
                    critic[b, 3, k] = ds_w[b, k]


@njit(cache=True, nogil=True)
def fixed_point_sum(counts, rq_t):  # pragma: no cover - compiled
    """(R, w*w) float64 ``counts (R, C) @ rq_t (C, w*w)`` over the nonzero counts only: the
    products and sums of small integer counts with the fixed-point matrix are integers below
    2**53, exact in any order, so this equals the full product bit for bit."""
    out = np.zeros((counts.shape[0], rq_t.shape[1]))
    for e in range(counts.shape[0]):
        for c in range(counts.shape[1]):
            x = np.float64(counts[e, c])
            if x != 0.0:
                for k in range(rq_t.shape[1]):
                    out[e, k] += x * rq_t[c, k]
    return out


# ---------------------------------------------------------------------------- env step


@njit(cache=True, nogil=True, error_model="numpy")
def advance(rows, actions, pos, free_next, dist, shaped, bonus, reward, found, cost, t,
            idle_streak, history):  # pragma: no cover - compiled
    """Move the team of each env in ``rows`` (``TargetLocalizationEnv.step``, actions checked
    already): team reward Eq. 5/8 (shaped: +1 if the team's best BFS distance fell, else -1,
    minus the agents that moved) or Eq. 9 (minus the movers, + ``bonus`` on the target), the
    target found, cost, time, idle streak and the position history."""
    n = pos.shape[1]
    slots = history.shape[1]
    for j in range(len(rows)):
        b = rows[j]
        moved = 0
        before, after = dist[b, pos[b, 0]], dist[b, free_next[pos[b, 0], actions[b, 0]]]
        for i in range(n):
            old, a = pos[b, i], actions[b, i]
            new = free_next[old, a]
            moved += a != 0
            before, after = min(before, dist[b, old]), min(after, dist[b, new])
            pos[b, i] = new
        found[b] = after == 0
        if shaped:
            reward[b] = (1.0 if after < before else -1.0) - moved
        else:
            reward[b] = -moved + bonus * (after == 0)
        cost[b] += moved
        t[b] += 1
        idle_streak[b] = idle_streak[b] + 1 if moved == 0 else 0
        for i in range(n):
            history[b, t[b] % slots, i] = pos[b, i]


@njit(cache=True, nogil=True)
def record_readings(rows, cells, taken, readings, visits, reading_sum):  # pragma: no cover
    """Readings ``taken`` (R, N) at ``cells`` (R, N) of envs ``rows``: the last one per cell
    (the last agent's, when agents share a cell), one more visit and the sum, agent by agent."""
    for j in range(len(rows)):
        b = rows[j]
        for i in range(cells.shape[1]):
            c = cells[j, i]
            readings[b, c] = taken[j, i]
            visits[b, c] += 1.0
            reading_sum[b, c] += taken[j, i]


@njit(cache=True, nogil=True)
def action_masks(env_rows, pos, walls, rows, cols, moves, idle_streak, idle_limit, mask):
    """``mask[b]`` for the envs ``env_rows``: at each agent's cell, the moves ``_allowed``
    allows; idle (move 0) only while the team's idle streak is under the limit."""
    for j in range(len(env_rows)):
        b = env_rows[j]
        for i in range(pos.shape[1]):
            r, c = pos[b, i] // cols, pos[b, i] % cols
            for a in range(moves.shape[0]):
                mask[b, i, a] = _allowed(walls[b], rows, cols, r, c, moves[a, 0], moves[a, 1])
            mask[b, i, 0] = mask[b, i, 0] and idle_streak[b] < idle_limit
