"""The update equations of (Bayesian) joint factor analysis regression, from moments alone.

The compiled loop behind `torchjfa.estimators.JFA` and `BayesianJFA` (``_jfa.py``): the
E-step, Q(w)/Q(alpha) and M-step updates, and the lower bound of ``docs/bayesian-jfa.md``, in
standardised units, plus SQUAREM's extrapolation (Varadhan and Roland, Scand. J. Stat. 2008)
used to speed up the slow directions. Each iteration costs one ``d x d`` mat-vec, whatever ``N``.

Why Numba here: after the single pass over the data, the loop works on ``O(d^2)`` numbers
(``d`` is a few hundred at most) for thousands of iterations. Written as NumPy array operations
its time was per-operation overhead, not arithmetic (about 65 us per iteration at ``d = 77``,
some 60 operations of about 1 us; torch's are 3 to 5 us each), and the iterations cost many
times the pass over the data. Compiled as loops over the inputs, an iteration costs what its
arithmetic costs, about 3 to 4 us at ``d = 77`` (``scripts/bench_estimators.py`` prints it).
The loop runs on CPU float64 NumPy copies of the moments, whatever the device of the data; the
estimators hand tensors on the data's device back. It is compiled on first use and cached on
disk by Numba (``cache=True``), without fast-math: the arithmetic is IEEE float64, as written.

The state is one ``(9, d)`` array plus ``psi_y``; its rows are `_MZ`, `_MX` (the posterior
means ``<w_z>``, ``<w_x>``), `_VZ`, `_VX` (their variances; 0 for maximum likelihood), `_WZ`,
`_WX` (second moments ``<w^2>``), `_B` (the rate of Q(alpha), ``<alpha> = a / b`` with
``a = a0 + 1``, or ``a0 + 1/2`` when alpha governs ``w_z`` alone; unused for maximum likelihood), `_PZ`, `_PX` (psi_z, psi_x). The E-step writes its expected
statistics into one ``(5, d)`` array with rows `_K` (the noisy-input predictor ``k``), `_SZZ`,
`_STT`, `_SZT`, `_SXT` and returns the scalars ``R = sum 1/D``, ``c = psi_y + R`` and the
residual sum of squares ``S_ee``.
"""

from __future__ import annotations

import math
import os

import numpy as np
from numba import njit

from .._notes import note

_LOG_2PI = math.log(2.0 * math.pi)
_STEP_GROWTH = 4.0  # SQUAREM: growth of the largest step after a step at the cap is accepted
_MZ, _MX, _VZ, _VX, _WZ, _WX, _B, _PZ, _PX = range(9)
_K, _SZZ, _STT, _SZT, _SXT = range(5)
# the loop's scalars, kept in one float array so that a fit can run in blocks (progress bar)
_C_COUNT, _C_L, _C_STEP, _C_ACC, _C_ESTEP, _C_PSY, _C_R, _C_C, _C_SEE = range(9)
REASONS = ("max_iter", "bound", "coef")
_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}


@njit(inline="always", **_JIT)
def _log_acc(acc, x):
    """Multiply ``x > 0`` into the running product ``acc = (prod, logs)`` of a sum of logs.

    The log is taken only when the product leaves [1e-64, 1e64], so a sum of ``d`` logs costs
    a few calls to ``log``, not ``d`` (the bound's three sums of logs were most of an E-step).
    Factors within 1e+-244 cannot overflow or underflow it. Finish with `_log_end`.
    """
    prod = acc[0] * x
    if 1e-64 < prod < 1e64:
        return prod, acc[1]
    return 1.0, acc[1] + math.log(prod)


@njit(inline="always", **_JIT)
def _log_end(acc):
    return acc[1] + math.log(acc[0])


@njit(**_JIT)
def _estep(xx, dg, xy, yy, n, st, psy, bayes, a, b0, lam, bound, es, work):
    """The note's E-step, Q(z, t) and its expected statistics, and the lower bound there.

    Writes ``es`` (see the module docstring); ``work`` is a ``(7, d)`` scratch array and
    ``dg`` the diagonal of ``xx``. The bound is evaluated with this Q(z, t), i.e. at its
    optimum for the state (for maximum likelihood it is then the log-likelihood), without the
    state-independent terms of `bound_const`; ``bound=False`` skips it (returns NaN). Returns
    ``(R, c, S_ee, L)``.

    The loops over inputs hold no sums, so that they vectorise (IEEE arithmetic, no
    reordering); the sums over inputs are separate short loops.
    """
    d = xy.shape[0]
    k = es[_K]
    iA, E, F, invD, s_xe, lg, per = work[0], work[1], work[2], work[3], work[4], work[5], work[6]
    for m in range(d):
        i0 = 1.0 / st[_PZ, m]
        i1 = 1.0 / st[_PX, m]
        mi0 = st[_MZ, m] * i0
        mi1 = st[_MX, m] * i1
        A = 1.0 + st[_WZ, m] * i0 + st[_WX, m] * i1
        ia = 1.0 / A
        e = mi0 * ia
        D = i0 - mi0 * e
        iD = 1.0 / D
        iA[m] = ia
        E[m] = e
        F[m] = mi1 * ia
        invD[m] = iD
        k[m] = e * mi1 * iD  # the noisy-input predictor, eq. (3)
        lg[m] = st[_PZ, m] * st[_PX, m] * A * D  # for the bound
    R = 0.0
    for m in range(d):
        R += invD[m]
    c = psy + R
    ic = 1.0 / c
    s_xe[:] = xy
    for j in range(d):  # the one d x d product, X^T e = X^T y - (X^T X) k, column by column
        kj = k[j]
        row = xx[j]  # = column j (symmetric): contiguous, so the inner loop vectorises
        for m in range(d):
            s_xe[m] -= row[m] * kj
    S_ee = yy
    for m in range(d):
        S_ee -= k[m] * (xy[m] + s_xe[m])
    for m in range(d):
        g = dg[m]
        e = E[m]
        f = F[m]
        rho = invD[m] * ic
        rs = rho * s_xe[m]
        szx = k[m] * g + rs  # sum <z> x
        sz2 = k[m] * (szx + rs) + S_ee * rho * rho  # sum <z>^2
        szz_d = invD[m] - rho * invD[m]  # diag Sigma_zz
        ezd = e * szz_d  # diag Sigma_zt
        ct0 = e * sz2 + f * szx  # sum <z><t>
        sxt = e * szx + f * g
        stt = e * ct0 + f * sxt + n * (iA[m] + e * ezd)
        szt = ct0 + n * ezd
        szz = sz2 + n * szz_d
        es[_SZZ, m] = szz
        es[_STT, m] = stt
        es[_SZT, m] = szt
        es[_SXT, m] = sxt
        # the bound: -1/2 sum_m [...] collects the per-input terms; these are the ones
        # without logs (and without the 2 a log b_m - log V_zm V_xm of the Bayesian model)
        qz = st[_WZ, m] * stt - 2.0 * st[_MZ, m] * szt + szz
        qx = st[_WX, m] * stt - 2.0 * st[_MX, m] * sxt + g
        pm = qz / st[_PZ, m] + qx / st[_PX, m] + stt
        if bayes:
            if lam < 0.0:  # one alpha_m shared by w_zm and w_xm
                pm += 2.0 * a * (0.5 * (st[_WZ, m] + st[_WX, m]) + b0) / st[_B, m]
            else:  # alpha_m for w_zm only; w_xm ~ N(0, 1 / lam)
                pm += 2.0 * a * (0.5 * st[_WZ, m] + b0) / st[_B, m] + lam * st[_WX, m]
        per[m] = pm
    if not bound:
        return R, c, S_ee, math.nan
    total = 0.0
    acc = (1.0, 0.0)  # sum_m log(psi_z psi_x A D)
    for m in range(d):
        total += per[m]
        acc = _log_acc(acc, lg[m])
    total += n * _log_end(acc)
    if bayes:
        lb = (1.0, 0.0)  # sum_m log b_m
        lv = (1.0, 0.0)  # sum_m log(V_zm V_xm)
        for m in range(d):
            lb = _log_acc(lb, st[_B, m])
            lv = _log_acc(lv, st[_VZ, m] * st[_VX, m])
        total += 2.0 * a * _log_end(lb) - _log_end(lv)
    L = -0.5 * n * math.log(c) - (psy * S_ee / c + n * R) / (2.0 * c) - 0.5 * total
    return R, c, S_ee, L


@njit(**_JIT)
def _update(dg, n, es, R, c, S_ee, st, psy, bayes, a, b0, lam, floor, fixed_x, floor_y):
    """Q(w_z), Q(w_x), Q(alpha) (or the maximum-likelihood W), then the M-step for the psi's.

    Updates ``st`` in place from the E-step's ``es``; returns the new ``psi_y``.
    """
    d = dg.shape[0]
    for m in range(d):
        i0 = 1.0 / st[_PZ, m]
        i1 = 1.0 / st[_PX, m]
        stt = es[_STT, m]
        szt = es[_SZT, m]
        sxt = es[_SXT, m]
        if bayes:
            ea = a / st[_B, m]
            vz = 1.0 / (stt * i0 + ea)
            vx = 1.0 / (stt * i1 + (ea if lam < 0.0 else lam))
            mz = vz * szt * i0
            mx = vx * sxt * i1
        else:
            vz = 0.0
            vx = 0.0
            mz = szt / stt
            mx = sxt / stt
        wz = mz * mz + vz
        wx = mx * mx + vx
        st[_MZ, m] = mz
        st[_MX, m] = mx
        st[_VZ, m] = vz
        st[_VX, m] = vx
        st[_WZ, m] = wz
        st[_WX, m] = wx
        if bayes:
            st[_B, m] = 0.5 * (wz + wx if lam < 0.0 else wz) + b0
        st[_PZ, m] = max((wz * stt - 2.0 * mz * szt + es[_SZZ, m]) / n, floor)
        if not fixed_x:
            st[_PX, m] = max((wx * stt - 2.0 * mx * sxt + dg[m]) / n, floor)
    r = psy / c
    return max(r * r * S_ee / n + r * R, floor_y)


@njit(**_JIT)
def _packed_rows(bayes, fixed_x):
    """The state rows in a packed vector, in order (padded with -1 to one length); the first
    two, the means, are packed as they are, the others in log."""
    px = -1 if fixed_x else _PX
    if bayes:
        return (_MZ, _MX, _VZ, _VX, _B, _PZ, px)
    return (_MZ, _MX, _PZ, px, -1, -1, -1)


@njit(**_JIT)
def th_size(d, bayes, fixed_x):
    """Length of a packed state (`_pack`) for ``d`` inputs: the rows of `_packed_rows` that
    are not -1, ``d`` entries each, and psi_y."""
    return ((6 if bayes else 3) + (0 if fixed_x else 1)) * d + 1


_ULP = 2.0**-52  # a positive float64's bits times this: 1023 + a piecewise-linear log2
_LO = float(np.float64(1e-300).view(np.int64)) * _ULP  # the range the packed values are held to
_HI = float(np.float64(1e300).view(np.int64)) * _ULP


@njit(inline="always", **_JIT)
def _bitlog(x):
    """`_pack`'s log of one positive float: its bit pattern as an integer, times 2^-52."""
    one = np.empty(1)
    one[0] = x
    return one.view(np.int64)[0] * _ULP


@njit(inline="always", **_JIT)
def _unlog_bits(t, lo):
    """Inverse of `_bitlog` as the bit pattern, held to [lo, 1e300] in packed units (NaN gives
    lo); write it through an int64 view of the float64 destination."""
    if not t >= lo:
        t = lo
    return np.int64(min(t, _HI) / _ULP)


@njit(inline="always", **_JIT)
def _unlog(t, lo):
    """Inverse of `_bitlog` for one float (see `_unlog_bits`)."""
    one = np.empty(1, dtype=np.int64)
    one[0] = _unlog_bits(t, lo)
    return one.view(np.float64)[0]


@njit(**_JIT)
def _pack(st, psy, bayes, fixed_x, th):
    """Write the free entries of a state into ``th``: means as they are, variances in log.

    The "log" of a variance is its float64 bit pattern read as an integer and scaled by
    2^-52: 1023 + log2(x) to within 0.09, exact at powers of 2, monotone, continuous, and
    invertible (`_unpack`) to within about 1e-13 relative (the 63-bit integer is rounded to a
    53-bit float). SQUAREM only needs a map that keeps variances positive and
    spreads their orders of magnitude evenly; this one costs an integer conversion where
    ``math.log`` costs most of a sweep.
    """
    d = st.shape[1]
    j = 0
    rows = _packed_rows(bayes, fixed_x)
    n_rows = th.shape[0] // d
    for i in range(n_rows):
        row = st[rows[i]]
        if i < 2:
            th[j : j + d] = row
        else:
            bits = row.view(np.int64)
            for m in range(d):
                th[j + m] = bits[m] * _ULP
        j += d
    th[j] = _bitlog(psy)


@njit(**_JIT)
def _unpack(th, like, bayes, floor, fixed_x, floor_y, out):
    """Inverse of `_pack` into ``out``; the rows not packed (psi_x if fixed; V and b for
    maximum likelihood) are copied from ``like``. Returns psi_y."""
    d = like.shape[1]
    out[:] = like
    rows = _packed_rows(bayes, fixed_x)
    n_rows = th.shape[0] // d
    lo_p, lo_y = _bitlog(floor), _bitlog(floor_y)
    j = 0
    for i in range(n_rows):
        r = rows[i]
        if i < 2:
            out[r] = th[j : j + d]
        else:
            lo = lo_p if r >= _PZ else _LO
            bits = out[r].view(np.int64)
            for m in range(d):
                bits[m] = _unlog_bits(th[j + m], lo)
        j += d
    for m in range(d):
        out[_WZ, m] = out[_MZ, m] * out[_MZ, m] + out[_VZ, m]
        out[_WX, m] = out[_MX, m] * out[_MX, m] + out[_VX, m]
    return _unlog(th[j], lo_y)


@njit(inline="always", **_JIT)
def _coef_m(st, bayes, m):
    """Eq. (4) for input m: ``<w_z><w_x> / <w_x^2>`` (0, not 0/0, when pruned); ``w_z / w_x``
    for maximum likelihood."""
    if bayes:
        return st[_MZ, m] * st[_MX, m] / st[_WX, m]
    return st[_MZ, m] / st[_MX, m]


@njit(**_JIT)
def _coef(st, bayes):
    """Eq. (4) for every input, shape ``(d,)``."""
    out = np.empty(st.shape[1])
    for m in range(st.shape[1]):
        out[m] = _coef_m(st, bayes, m)
    return out


@njit(**_JIT)
def _coef_change(st, bayes, coef):
    """Overwrite ``coef`` with eq. (4) of the state (`_coef`); return the norm of the change."""
    dc = 0.0
    for m in range(coef.shape[0]):
        new = _coef_m(st, bayes, m)
        dc += (new - coef[m]) ** 2
        coef[m] = new
    return math.sqrt(dc)


@njit(**_JIT)
def _squarem(th0, th1, th2, step_max, out):
    """SQUAREM's extrapolation (Varadhan and Roland 2008, scheme S3) from two plain sweeps.

    With ``r = th1 - th0`` and ``v = th2 - 2 th1 + th0`` (packed states, `_pack`),
    ``alpha = clamp(||r|| / ||v||, 1, step_max)`` and the new point is ``th0 + 2 alpha r +
    alpha^2 v`` (``alpha = 1`` gives ``th2``), written into ``out``. Returns ``(ok, alpha)``.
    """
    sr2 = 0.0
    sv2 = 0.0
    for i in range(th0.shape[0]):
        r = th1[i] - th0[i]
        v = th2[i] - th1[i] - r
        sr2 += r * r
        sv2 += v * v
    if not (sv2 > 0.0 and math.isfinite(sr2 / sv2)):
        return False, 1.0
    alpha = min(max(math.sqrt(sr2 / sv2), 1.0), step_max)
    if alpha == 1.0:
        return False, alpha
    for i in range(th0.shape[0]):
        r = th1[i] - th0[i]
        v = th2[i] - th1[i] - r
        out[i] = th0[i] + (2.0 * alpha) * r + (alpha * alpha) * v
    return True, alpha


@njit(**_JIT)
def start(xx, dg, xy, yy, n, st, psy, hp, const, es, work):
    """The first sweep from the initial state (no bound: the variances are still 0) and the
    E-step after it; updates ``st`` in place. Returns the loop's scalars (``ctl``)."""
    bayes, a, b0, floor, fixed_x, floor_y, lam = hp
    R, c, S_ee, _ = _estep(xx, dg, xy, yy, n, st, psy, bayes, a, b0, lam, False, es, work)
    psy = _update(dg, n, es, R, c, S_ee, st, psy, bayes, a, b0, lam, floor, fixed_x, floor_y)
    R, c, S_ee, L = _estep(xx, dg, xy, yy, n, st, psy, bayes, a, b0, lam, True, es, work)
    ctl = np.zeros(9)
    ctl[_C_COUNT] = 1.0
    ctl[_C_L] = L + const
    ctl[_C_STEP] = 1.0
    ctl[_C_ESTEP] = 2.0
    ctl[_C_PSY], ctl[_C_R], ctl[_C_C], ctl[_C_SEE] = psy, R, c, S_ee
    return ctl


@njit(**_JIT)
def run(xx, dg, xy, yy, n, st, hp, const, es, work, ctl, hist, limit, max_iter, tol, ctol, acc):
    """EM sweeps, two at a time followed by a SQUAREM jump (if ``acc``), until a tolerance
    stops them, ``max_iter`` bounds are recorded, or ``limit`` is reached at the end of a cycle
    (to resume: call again with the same arrays). Updates ``st``, ``es``, ``ctl`` and ``hist``
    (the bound after each iteration) in place; returns the stop reason's index in `REASONS`,
    or -1 when paused at ``limit``.

    ``hp = (bayes, a0 + 1, b0, floor, fixed_x, floor_y)``; a trial jump is kept only if the
    bound does not decrease (NaN fails), so the recorded bounds never decrease.
    """
    bayes, a, b0, floor, fixed_x, floor_y, lam = hp
    scale = max(n, 1.0)
    count = int(ctl[_C_COUNT])
    L, step_max = ctl[_C_L], ctl[_C_STEP]
    n_acc, n_estep = int(ctl[_C_ACC]), int(ctl[_C_ESTEP])
    psy, R, c, S_ee = ctl[_C_PSY], ctl[_C_R], ctl[_C_C], ctl[_C_SEE]
    coef = _coef(st, bayes)
    reason = 0
    es_t, st_t = np.empty_like(es), np.empty_like(st)
    size = th_size(st.shape[1], bayes, fixed_x) if acc else 0
    th0, th1, th2, trial = np.empty(size), np.empty(size), np.empty(size), np.empty(size)
    fresh = False  # th0 holds the packed current state already
    while count < limit:
        if acc and not fresh:
            _pack(st, psy, bayes, fixed_x, th0)
        for sweep in range(2):
            psy = _update(
                dg, n, es, R, c, S_ee, st, psy, bayes, a, b0, lam, floor, fixed_x, floor_y
            )
            R, c, S_ee, L_new = _estep(
                xx, dg, xy, yy, n, st, psy, bayes, a, b0, lam, True, es, work
            )
            L_new += const
            n_estep += 1
            hist[count] = L_new
            count += 1
            dc = _coef_change(st, bayes, coef)
            dL = abs(L_new - L)
            L = L_new
            if dL <= tol * max(abs(L), scale):
                reason = 1
            elif dc <= ctol * math.sqrt(float(coef @ coef)):
                reason = 2
            if reason != 0 or count >= max_iter:
                break
            if acc:
                _pack(st, psy, bayes, fixed_x, th1 if sweep == 0 else th2)
        if reason != 0 or count >= max_iter:
            break
        if not acc:
            continue
        # unless a jump is accepted below, the current state is the second sweep's: th2
        th0, th2 = th2, th0
        fresh = True
        ok, alpha = _squarem(th2, th1, th0, step_max, trial)
        if not ok:
            if alpha >= step_max:
                step_max *= _STEP_GROWTH
            continue
        psy_t = _unpack(trial, st, bayes, floor, fixed_x, floor_y, st_t)
        R_t, c_t, S_t, L_t = _estep(
            xx, dg, xy, yy, n, st_t, psy_t, bayes, a, b0, lam, True, es_t, work
        )
        L_t += const
        n_estep += 1
        if L_t >= L:  # accepted only if the bound does not decrease (NaN fails)
            st[:] = st_t
            es[:] = es_t
            psy, R, c, S_ee, L = psy_t, R_t, c_t, S_t, L_t
            _coef_change(st, bayes, coef)
            hist[count] = L
            count += 1
            n_acc += 1
            fresh = False
            if alpha >= step_max:
                step_max *= _STEP_GROWTH
        elif alpha >= step_max:
            step_max = max(1.0, step_max / _STEP_GROWTH)
    ctl[_C_COUNT], ctl[_C_L], ctl[_C_STEP] = count, L, step_max
    ctl[_C_ACC], ctl[_C_ESTEP] = n_acc, n_estep
    ctl[_C_PSY], ctl[_C_R], ctl[_C_C], ctl[_C_SEE] = psy, R, c, S_ee
    if reason == 0 and count < max_iter:
        return -1
    return reason


def bound_const(n: float, d: int, hp: tuple) -> float:
    """State-independent terms of the bound (the 2 pi's, the Gamma prior, the entropies)."""
    bayes, a, b0, lam = hp[0], hp[1], hp[2], hp[6]
    const = -0.5 * n * _LOG_2PI * (1 + 3 * d) + n * d * (1.0 + _LOG_2PI)
    if bayes:
        from scipy.special import digamma

        dig = float(digamma(a))
        # Q(alpha) = Gamma(a, b): a = a0 + 1 with alpha shared by the two loadings, a0 + 1/2
        # with alpha on w_z alone; <log alpha> = digamma(a) - log b
        k = 1.0 if lam < 0.0 else 0.5  # loadings under alpha
        a0 = a - k
        per = (
            -k * _LOG_2PI  # the Gaussian priors under alpha
            + a0 * math.log(b0)  # the Gamma prior
            - math.lgamma(a0)
            + (a0 - 1.0 + k) * dig
            + k * (1.0 + _LOG_2PI)  # entropies of their Q(w): halves of log(2 pi e)
            + a  # entropy of Q(alpha)
            + math.lgamma(a)
            + (1.0 - a) * dig
        )
        if lam >= 0.0:  # w_x ~ N(0, 1 / lam): the prior's normaliser and Q(w_x)'s entropy
            per += 0.5 * math.log(lam) + 0.5
        const += d * per
    return const


def coef(st: np.ndarray, bayes: bool) -> np.ndarray:
    """Eq. (4) of a state (`_coef`), callable from Python."""
    return _coef(st, bayes)


def note_first_compile() -> None:
    """Say once, before the first fit of a process, when the loop is not in Numba's disk cache.

    Compiling takes about 10 s on this project's machines, once per machine (then Numba loads
    it from ``__pycache__`` or ``$NUMBA_CACHE_DIR`` in about 0.4 s per process).
    """
    if run.signatures:  # compiled or loaded in this process already
        return
    try:
        index = run._cache._cache_file._index_path  # Numba internals: skip the note if moved
    except AttributeError:
        return
    if not os.path.exists(index):
        note(
            "compiling the (Bayesian) JFA EM loop with Numba (about 10 s, once per machine; "
            f"cached in {os.path.dirname(index)})",
            key="numba-compile",
        )
