"""The terrain refinement's per-square arithmetic as compiled loops (numba) [Red01 Eq 4-5].

Written by hand because no library does it: these are the inner loops of ``optim/_terrain.py``, which
keeps the algorithm, the error budget and the decisions. As numpy expressions the same arithmetic took
about 200 whole-array passes per node, each through memory; compiled, each value is made once in
registers. Stages, in the order a level uses them:

* :func:`strip_geometry`: the float32 bound pass's geometry over a strip of a level's grid (the corners'
  unit directions, the squares' extent and longest-edge bounds, the cosines to the gaze, the retinal
  velocity from the chords between successive cameras). Its inner loops are branch-free (selects only),
  so LLVM makes them SIMD. One float32 rounding per operation, in the order the ``_EPS_*`` budget of
  ``optim/_terrain.py`` bounds (no fast-math: no contraction into fused multiply-adds, no reassociation).
  The decisions from it stay numpy (its SIMD ``log`` and ``cos``; numba calls scalar libm here).
* :func:`edge_decide`: the decisions from bounds of e on the edge arcs, for the squares the bound pass
  leaves open (float64).
* :func:`exact_terms`: the float64 test's extent, eccentricity and velocity, one square at a time.
* :func:`cull_squares` and :func:`level_leaves`: the field-of-view test and the leaf pass.

Units: metres, radians unless a name ends in ``deg``; velocities deg/s; H' cycles/deg.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

F = np.float32
_PI = math.pi
_DEG = 180.0 / math.pi


@njit(cache=True, error_model="numpy")
def _world_dirs(Y, X, Z, eye, U0, U1, U2):
    """float32 unit directions from ``eye`` (3,) of the grid nodes at heights ``Y`` (nr, nc), columns at
    x = ``X`` (nc,), rows at z = ``Z`` (nr,), in world axes, into U0, U1, U2 (nr, nc) float32. The x and
    z terms are per column / row (float64, rounded once)."""
    nr, nc = Y.shape
    for i in range(nr):
        dz = Z[i] - eye[2]
        dz32 = F(dz)
        dzz = F(dz * dz)
        for j in range(nc):
            dx = X[j] - eye[0]
            dy = F(Y[i, j] - eye[1])
            n = dy * dy
            n += F(dx * dx)
            n += dzz
            inv = F(1.0) / np.sqrt(n)  # a node at the eye: inf, then NaN, so undecided
            U0[i, j] = inv * F(dx)
            U1[i, j] = dy * inv
            U2[i, j] = inv * dz32


@njit(cache=True, error_model="numpy", inline="always")
def _rotated(dx, dy, z0, z1, z2, r00, r01, r10, r11, r20, r21):
    """The float32 unit direction R (p - eye), normalized, of one node: ``dx`` (float64) and ``dy``
    (float32) its offsets from the eye in x and y, ``z0..z2`` the float32 terms R_i2 dz of its row, ``r*0``
    the float64 and ``r*1`` the float32 entries of R's first two columns."""
    c0 = dy * r01
    c0 += F(r00 * dx)
    c0 += z0
    c1 = dy * r11
    c1 += F(r10 * dx)
    c1 += z1
    c2 = dy * r21
    c2 += F(r20 * dx)
    c2 += z2
    n = c0 * c0
    n += c1 * c1
    n += c2 * c2
    inv = F(1.0) / np.sqrt(n)
    return c0 * inv, c1 * inv, c2 * inv


@njit(cache=True, error_model="numpy")
def _rotated_dirs(Y, X, Z, eye, R, U0, U1, U2):
    """As :func:`_world_dirs`, rotated by ``R`` (3, 3): each component R_i . (p - eye), then normalized."""
    nr, nc = Y.shape
    for i in range(nr):
        dz = Z[i] - eye[2]
        z0, z1, z2 = F(R[0, 2] * dz), F(R[1, 2] * dz), F(R[2, 2] * dz)
        for j in range(nc):
            U0[i, j], U1[i, j], U2[i, j] = _rotated(X[j] - eye[0], F(Y[i, j] - eye[1]), z0, z1, z2, R[0, 0],
                                                    F(R[0, 1]), R[1, 0], F(R[1, 1]), R[2, 0], F(R[2, 1]))


def dirs32(Y, X, Z, eye, R=None):
    """float32 unit directions (three (nr, nc) arrays) of the grid nodes (heights ``Y`` (nr, nc) m, columns
    x = ``X`` (nc,), rows z = ``Z`` (nr,) m) seen from ``eye``, in world axes (``R`` None) or rotated by R."""
    Y = np.ascontiguousarray(Y, np.float64)
    U = [np.empty(Y.shape, F) for _ in range(3)]
    X, Z, eye = (np.ascontiguousarray(a, np.float64) for a in (X, Z, eye))
    if R is None:
        _world_dirs(Y, X, Z, eye, *U)
    else:
        _rotated_dirs(Y, X, Z, eye, np.ascontiguousarray(R, np.float64), *U)
    return U


@njit(cache=True, error_model="numpy", inline="always")
def _max(a, b):
    """max(a, b) that propagates NaN as np.maximum does (a select, not a branch)."""
    return a if (a >= b) | (a != a) else b


@njit(cache=True, error_model="numpy", inline="always")
def _min(a, b):
    """min(a, b) that propagates NaN as np.minimum does."""
    return a if (a <= b) | (a != a) else b


@njit(cache=True, error_model="numpy", inline="always")
def _arc_up_deg(c, series, chord_max, half_pi, k_deg):
    """Upper bound (deg, float32) of the arc 2 asin(c / 2) with chord ``c``: c + c^3 series (rad) for
    chords up to ``chord_max``, pi c / 2 beyond."""
    x = c * c
    x *= series
    x += F(1.0)
    x *= c
    return (c * half_pi if c > chord_max else x) * k_deg


@njit(cache=True, error_model="numpy")
def _velocity(Y, X, Z, U0, U1, U2, eyes, Ss, series, ve, eps_n, chord_max, LO, HI):
    """Per node (nr, nc) float32 bounds (LO, HI) of the sum over the previous steps of the angle (rad)
    between successive directions, from float32 chords; ``eyes`` (m, 3) and ``Ss`` (m, 3, 3): the previous
    cameras' eyes and R_0^T R_j (directions in the current camera's world axes), most recent first."""
    nr, nc = Y.shape
    m = eyes.shape[0]
    half_pi = F(_PI / 2)
    px = np.empty(nc, F)
    py = np.empty(nc, F)
    pz = np.empty(nc, F)
    s1 = np.empty(nc, F)
    s3 = np.empty(nc, F)
    for i in range(nr):
        for j in range(nc):
            px[j] = U0[i, j]
            py[j] = U1[i, j]
            pz[j] = U2[i, j]
            s1[j] = F(0.0)
            s3[j] = F(0.0)
        for k in range(m):
            dz = Z[i] - eyes[k, 2]
            z0, z1, z2 = F(Ss[k, 0, 2] * dz), F(Ss[k, 1, 2] * dz), F(Ss[k, 2, 2] * dz)
            r01, r11, r21 = F(Ss[k, 0, 1]), F(Ss[k, 1, 1]), F(Ss[k, 2, 1])
            r00, r10, r20 = Ss[k, 0, 0], Ss[k, 1, 0], Ss[k, 2, 0]
            ex, ey = eyes[k, 0], eyes[k, 1]
            for j in range(nc):
                c0, c1, c2 = _rotated(X[j] - ex, F(Y[i, j] - ey), z0, z1, z2, r00, r01, r10, r11, r20, r21)
                a = px[j] - c0
                d2 = a * a
                a = py[j] - c1
                d2 += a * a
                a = pz[j] - c2
                d2 += a * a
                d = np.sqrt(d2)
                s1[j] += d
                s3[j] += d2 * d
                px[j] = c0
                py[j] = c1
                pz[j] = c2
        for j in range(nc):
            # [s1 + s3 / 24 - ve, s1 + s3 series + ve] when every chord is <= chord_max (so when s1 is),
            # else [s1 - n eps, pi / 2 (s1 + n eps)]
            a = s1[j]
            big = a > chord_max
            lo = s3[j] * F(1.0 / 24.0)
            lo += a
            hi = s3[j] * series
            hi += a
            LO[i, j] = (a - eps_n) if big else (lo - ve)
            HI[i, j] = ((a + eps_n) * half_pi) if big else (hi + ve)


@njit(cache=True, error_model="numpy")
def _squares(U0, U1, U2, gw, periphery, moving, LO, HI, scale, eps_chord, series, chord_max, mu,
             H_S, H_N, X_HI, W, KMAX, V_HI, V_LO):
    """Per square of a strip (nr - 1, nc - 1), from its corners' float32 directions U0, U1, U2 (nr, nc):
    ``H_S`` the H' a sure split needs (1 / (2 x_lo (1 - mu)), x_lo the extent's lower bound in deg),
    ``X_HI`` the extent's upper bound (deg), ``H_N`` the H' below which surely no split
    (0.5 / ((1 + mu) x_hi)), ``W`` the longest edge's upper bound (deg), with ``periphery`` ``KMAX`` the
    largest cosine of a corner to the gaze ``gw`` (3,), with ``moving`` ``V_HI`` / ``V_LO`` the least over the
    corners of the velocity bounds HI / LO (nr, nc) times ``scale`` (deg/s). Each inner loop is branch-free
    (selects only), so LLVM makes it SIMD."""
    nr, nc = U0.shape
    k_deg = F(_DEG)
    half_pi = F(_PI / 2)
    s_fac = F(_DEG * 2.0 * (1.0 - mu))
    n_fac = F(0.5 / (1.0 + mu))
    g0, g1, g2 = gw[0], gw[1], gw[2]
    for i in range(nr - 1):
        for j in range(nc - 1):
            # squared chords: the four edges (north, south, west, east), the two diagonals
            t = U0[i, j] - U0[i, j + 1]
            en = t * t
            t = U1[i, j] - U1[i, j + 1]
            en += t * t
            t = U2[i, j] - U2[i, j + 1]
            en += t * t
            t = U0[i + 1, j] - U0[i + 1, j + 1]
            es = t * t
            t = U1[i + 1, j] - U1[i + 1, j + 1]
            es += t * t
            t = U2[i + 1, j] - U2[i + 1, j + 1]
            es += t * t
            t = U0[i, j] - U0[i + 1, j]
            ew = t * t
            t = U1[i, j] - U1[i + 1, j]
            ew += t * t
            t = U2[i, j] - U2[i + 1, j]
            ew += t * t
            t = U0[i, j + 1] - U0[i + 1, j + 1]
            ee = t * t
            t = U1[i, j + 1] - U1[i + 1, j + 1]
            ee += t * t
            t = U2[i, j + 1] - U2[i + 1, j + 1]
            ee += t * t
            t = U0[i, j] - U0[i + 1, j + 1]
            q1 = t * t
            t = U1[i, j] - U1[i + 1, j + 1]
            q1 += t * t
            t = U2[i, j] - U2[i + 1, j + 1]
            q1 += t * t
            t = U0[i, j + 1] - U0[i + 1, j]
            q2 = t * t
            t = U1[i, j + 1] - U1[i + 1, j]
            q2 += t * t
            t = U2[i, j + 1] - U2[i + 1, j]
            q2 += t * t
            em = _max(_max(en, es), _max(ew, ee))  # the longest edge
            c = np.sqrt(_max(_max(q1, q2), em))  # the largest chord
            h_s = _max(c - eps_chord, F(0.0)) * s_fac  # x_lo (rad) times 2 (1 - mu) deg / rad
            H_S[i, j] = F(1.0) / h_s  # the H' a sure split needs (inf where x_lo = 0)
            c += eps_chord
            x_hi = _arc_up_deg(c, series, chord_max, half_pi, k_deg)
            X_HI[i, j] = x_hi
            H_N[i, j] = n_fac / x_hi  # the H' below which surely no split
            W[i, j] = _arc_up_deg(_min(np.sqrt(em) + eps_chord, c), series, chord_max, half_pi, k_deg)
        if periphery:
            for j in range(nc - 1):
                ka = U0[i, j] * g0
                ka += U1[i, j] * g1
                ka += U2[i, j] * g2
                kb = U0[i, j + 1] * g0
                kb += U1[i, j + 1] * g1
                kb += U2[i, j + 1] * g2
                kc = U0[i + 1, j + 1] * g0
                kc += U1[i + 1, j + 1] * g1
                kc += U2[i + 1, j + 1] * g2
                kd = U0[i + 1, j] * g0
                kd += U1[i + 1, j] * g1
                kd += U2[i + 1, j] * g2
                KMAX[i, j] = _max(_max(ka, kb), _max(kc, kd))
        if moving:
            for j in range(nc - 1):
                V_HI[i, j] = _min(_min(HI[i, j], HI[i, j + 1]), _min(HI[i + 1, j + 1], HI[i + 1, j])) * scale
                V_LO[i, j] = _min(_min(LO[i, j], LO[i, j + 1]), _min(LO[i + 1, j + 1], LO[i + 1, j])) * scale


def strip_geometry(Y, X, Z, eye, gw, periphery, moves, scale, eps):
    """The float32 geometry of the size test over one strip of a level's grid (``optim._terrain._strip_bounds``
    makes the decisions from it).

    ``Y`` (nr, nc) heights (m) of the strip's grid nodes, columns at x = ``X`` (nc,), rows at z = ``Z``
    (nr,) m; ``eye`` (3,) m; ``gw`` (3,) the unit gaze (world axes); ``periphery``: also the terms of e;
    ``moves``: None, or (eyes (m, 3), R_0^T R_j (m, 3, 3)) of the previous cameras for the measured
    velocity, ``scale`` deg/s per radian of angle sum; ``eps``: (eps_chord, series, chord_max, mu).

    Returns ``(U, h_s, h_n, x_hi, w, kmax, v_hi, v_lo)``: ``U`` the nodes' float32 unit directions (three
    (nr, nc) arrays, world axes); per square (nr - 1, nc - 1) float32 (see :func:`_squares`): ``h_s``,
    ``h_n`` the H' bounds of a sure split / none, ``x_hi`` (deg) the extent's upper bound, ``w`` (deg) the
    longest edge's, ``kmax`` the largest cosine of a corner to the gaze (None without ``periphery``),
    ``v_hi`` / ``v_lo`` (deg/s) bounds of the retinal velocity (None without ``moves``). A corner at an eye
    gives NaN in its squares' values (NaN propagates as through numpy's minima and maxima).
    """
    eps_chord, series, chord_max = (F(x) for x in eps[:3])
    mu = float(eps[3])
    Y = np.ascontiguousarray(Y, np.float64)
    X, Z, eye = (np.ascontiguousarray(a, np.float64) for a in (X, Z, eye))
    nr, nc = Y.shape
    U = [np.empty((nr, nc), F) for _ in range(3)]
    _world_dirs(Y, X, Z, eye, *U)
    if moves is not None:
        eyes, Ss = moves
        m = len(eyes)
        LO, HI = np.empty((nr, nc), F), np.empty((nr, nc), F)
        _velocity(Y, X, Z, *U, eyes, Ss, series, F(1.02 * m * float(eps_chord)), F(m * float(eps_chord)),
                  chord_max, LO, HI)
    else:
        LO = HI = np.empty((1, 1), F)
    sq = (nr - 1, nc - 1)
    empty = np.empty((1, 1), F)
    H_S, H_N, X_HI, W = (np.empty(sq, F) for _ in range(4))
    KMAX = np.empty(sq, F) if periphery else empty
    V_HI, V_LO = (np.empty(sq, F), np.empty(sq, F)) if moves is not None else (empty, empty)
    _squares(*U, np.asarray(gw, F), bool(periphery), moves is not None, LO, HI, F(scale), eps_chord, series,
             chord_max, mu, H_S, H_N, X_HI, W, KMAX, V_HI, V_LO)
    return (U, H_S, H_N, X_HI, W, KMAX if periphery else None,
            V_HI if moves is not None else None, V_LO if moves is not None else None)


@njit(cache=True, error_model="numpy")
def edge_decide(ri, ci, U0, U1, U2, g, hs, hn, gs, gn, far, xi, ms, mr, ed, yes, no):
    """The size test's decisions from bounds of e itself for the squares (``ri``, ``ci``) of a strip
    (``optim._terrain._edge_refine`` documents the argument), into ``yes`` / ``no`` (K,) bool. float64
    arithmetic on the float32 corner directions U0, U1, U2 (nr, nc); ``g`` (3,) the gaze (world axes);
    per square (K,) float64: ``hs`` / ``hn`` the H' of a sure split / none, ``gs`` / ``gn`` G at the
    largest / smallest velocity, ``far`` bool where the gaze is surely outside; ``xi``, ``ms``, ``mr`` the
    acuity's display cap and eccentricity constants; ``ed`` the directions' error bound."""
    m0 = min(1.0, ms)
    rad = math.pi / 180.0
    g0, g1, g2 = g[0], g[1], g[2]
    t = 6.0 * ed
    P0, P1, P2 = np.empty(4), np.empty(4), np.empty(4)
    for k in range(len(ri)):
        i, j = ri[k], ci[k]
        q_s = hs[k] / gs[k]
        q_n = hn[k] / gn[k]
        # M(e) >= q iff q <= M(0) and e <= E(q) = (sqrt(m_scale / q) - 1) / m_rate (deg); E less / more a
        # little for the float64 path's own rounding of e, in radians, capped at pi (NaN stays NaN)
        y_ok = (hs[k] <= xi) & (q_s <= m0)
        n_ok = (hn[k] > xi) | (q_n > m0)
        E_s = ((math.sqrt(ms / q_s) - 1.0) / mr - 1e-7) * rad
        E_n = ((math.sqrt(ms / q_n) - 1.0) / mr + 1e-7) * rad
        E_s = 0.0 if E_s < 0.0 else (math.pi if E_s > math.pi else E_s)
        E_n = 0.0 if E_n < 0.0 else (math.pi if E_n > math.pi else E_n)
        cs, ss, cn, sn = math.cos(E_s), math.sin(E_s), math.cos(E_n), math.sin(E_n)
        half_s, half_n = E_s >= math.pi / 2, E_n >= math.pi / 2
        # the corners NW, NE, SE, SW; edge e runs from corner e to corner e + 1
        for e, (a, b) in enumerate(((i, j), (i, j + 1), (i + 1, j + 1), (i + 1, j))):
            P0[e], P1[e], P2[e] = U0[a, b], U1[a, b], U2[a, b]
        if not np.isfinite(P0.sum() + P1.sum() + P2.sum()):  # a corner at the eye: neither (as NaN does in numpy)
            yes[k] = False
            no[k] = False
            continue
        within = False
        beyond = True
        all_pos = all_neg = all_front = True
        any_pos = any_neg = any_back = False
        gmax = -np.inf
        pq_min = np.inf
        for e in range(4):
            f = (e + 1) % 4
            p0, p1, p2, r0, r1, r2 = P0[e], P1[e], P2[e], P0[f], P1[f], P2[f]
            gP = g0 * p0 + g1 * p1 + g2 * p2  # the cosine to the gaze of each end
            gQ = g0 * r0 + g1 * r1 + g2 * r2
            pq = p0 * r0 + p1 * r1 + p2 * r2
            n0, n1, n2 = p1 * r2 - p2 * r1, p2 * r0 - p0 * r2, p0 * r1 - p1 * r0
            nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            side = g0 * n0 + g1 * n1 + g2 * n2
            gn_ = abs(side)
            t1, t2 = gQ - pq * gP, gP - pq * gQ
            on = (t1 > t) & (t2 > t)  # the foot surely on the arc
            off = (t1 < -t) | (t2 < -t)  # surely off it
            cmax = max(gP, gQ)
            s_hi = (gn_ + 2 * ed) / (nn - 2 * ed) if nn > 2 * ed else np.inf
            s_lo = (gn_ - 2 * ed) / (nn + 2 * ed)
            # some edge within E_s: its nearer end within it, or the foot on the arc and the circle within it
            within |= (cmax - ed >= cs) | (on & (half_s | (s_hi <= ss)))
            # every edge beyond E_n: the ends beyond it and, unless the foot is surely off the arc, the circle too
            beyond &= (cmax + ed < cn) & (off | (~half_n & (s_lo > sn)))
            all_pos &= side > 4 * ed
            all_neg &= side < -4 * ed
            all_front &= gP > 4 * ed
            any_pos |= side > 4 * ed
            any_neg |= side < -4 * ed
            any_back |= gP < -4 * ed
            gmax = max(gmax, gP)
            pq_min = min(pq_min, pq)
        # e = 0 only where the float64 path tests the gaze inside: the nearest corner surely within the
        # extent (the largest cosine to the gaze above the smallest between two corners)
        d02 = P0[0] * P0[2] + P1[0] * P1[2] + P2[0] * P2[2]  # the diagonals' cosines
        d13 = P0[1] * P0[3] + P1[1] * P1[3] + P2[1] * P2[3]
        tested = gmax - ed > min(min(pq_min, d02), d13) + 2 * ed
        inside = (all_pos | all_neg) & all_front & tested
        outside = far[k] | (any_pos & any_neg) | any_back
        yes[k] = y_ok & (inside | (outside & within))
        no[k] = n_ok | (outside & beyond)


@njit(cache=True, error_model="numpy", inline="always")
def _cull_one(zmin, zmax, i, j, s, eye, R, ca, sa, wide, hy):
    """(culled, contained) of square (i, j): its bounding sphere (about its box from ``zmin`` / ``zmax``,
    side ``s`` m) wholly outside / inside the field of view (``ca``, ``sa`` the cosine and sine of the half
    azimuth field, ``wide`` when that is >= 90 deg, ``hy`` the half elevation field, rad)."""
    margin = 1e-9
    lo, hi = zmin[i, j], zmax[i, j]
    c0, c1, c2 = (j + 0.5) * s - eye[0], 0.5 * (lo + hi) - eye[1], (i + 0.5) * s - eye[2]
    r = math.sqrt(0.5 * s * s + 0.25 * (hi - lo) ** 2)
    d0 = c0 * R[0, 0] + c1 * R[0, 1] + c2 * R[0, 2]
    d1 = c0 * R[1, 0] + c1 * R[1, 1] + c2 * R[1, 2]
    d2 = c0 * R[2, 0] + c1 * R[2, 1] + c2 * R[2, 2]
    dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    far = dist > r
    dd = max(dist, 1e-300)
    sin_rho = r / dd if far else 1.0
    u0, u1, u2 = d0 / dd, d1 / dd, d2 / dd
    dp = u0 * ca + u2 * sa  # signed distance (over dist) beyond the azimuth +hx half-plane
    dm = -u0 * ca + u2 * sa
    side = ((dp > sin_rho) & (dm > sin_rho)) if wide else ((dp > sin_rho) | (dm > sin_rho))
    el = math.asin(min(max(u1, -1.0), 1.0))
    rho = math.asin(min(max(sin_rho, 0.0), 1.0))
    culled = far & (side | (el - rho > hy) | (el + rho < -hy))
    ins = ((dp < -sin_rho - margin) | (dm < -sin_rho - margin)) if wide else \
        ((dp < -sin_rho - margin) & (dm < -sin_rho - margin))
    return culled, far & ins & (el + rho < hy - margin) & (el - rho > -hy + margin)


@njit(cache=True, error_model="numpy")
def cull_squares(zmin, zmax, ii, jj, s, eye, R, hx, hy, culled, contained):
    """The field-of-view test of the level's squares (``ii``, ``jj``) (K,) as ``optim._terrain._culled``
    describes it, into ``culled`` / ``contained`` (K,) bool: ``zmin`` / ``zmax`` the level's (2^l, 2^l)
    height bounds (m), ``s`` its square side (m), ``eye`` (3,) m, ``R`` (3, 3) the camera rotation, ``hx``,
    ``hy`` the half fields of view (rad). float64, one square at a time."""
    ca, sa = math.cos(hx), math.sin(hx)
    wide = hx >= math.pi / 2
    for k in range(len(ii)):
        culled[k], contained[k] = _cull_one(zmin, zmax, ii[k], jj[k], s, eye, R, ca, sa, wide, hy)


@njit(cache=True, error_model="numpy")
def level_leaves(sh, parent, split, finest, cull, known, zmin, zmax, s, eye, R, hx, hy):
    """The drawn leaves of level ``sh`` (m = 2^sh squares a side), in row-major order: ``parent`` (m/2,
    m/2) bool the level above's split map (its squares' children are this level's candidates; ignored
    for the root, m = 1), ``split`` (m, m) bool this level's (ignored where ``finest``: no square splits
    there, none has a finer neighbour). With ``cull``: ``known`` (m, m) int8 the refinement's cull states
    (0 unknown, 1 visible, 2 culled, 3 contained; at the finest level: 3 where the parent was contained,
    else 0), the unknown leaves get the field-of-view test (:func:`_cull_one` on ``zmin``, ``zmax``, side
    ``s``, ``eye``, ``R``, half fields ``hx``, ``hy``).

    Returns ``(rc, fan)``: (K, 2) int64 (row, column) and (K, 4) bool, the edges (north, east, south,
    west) whose neighbour is split (finer)."""
    m = 1 << sh
    ca, sa = math.cos(hx), math.sin(hx)
    wide = hx >= math.pi / 2
    buf = np.empty(m * m, np.int64)
    k = 0
    root = m == 1
    for i in range(m):
        pi = i >> 1
        for j in range(m):
            if not root and not parent[pi, j >> 1]:
                continue
            if not finest and split[i, j]:
                continue
            if cull:
                st = known[i, j]
                if st == 2:
                    continue
                if st == 0 and _cull_one(zmin, zmax, i, j, s, eye, R, ca, sa, wide, hy)[0]:
                    continue
            buf[k] = i * m + j
            k += 1
    rc = np.empty((k, 2), np.int64)
    fan = np.zeros((k, 4), np.bool_)
    for t in range(k):
        i, j = buf[t] >> sh, buf[t] & (m - 1)  # row and column by shift and mask
        rc[t, 0], rc[t, 1] = i, j
    if not finest:
        for t in range(k):
            i, j = rc[t, 0], rc[t, 1]
            fan[t, 0] = split[max(i - 1, 0), j] & (i > 0)
            fan[t, 1] = split[i, min(j + 1, m - 1)] & (j < m - 1)
            fan[t, 2] = split[min(i + 1, m - 1), j] & (i < m - 1)
            fan[t, 3] = split[i, max(j - 1, 0)] & (j > 0)
    return rc, fan


@njit(cache=True, error_model="numpy", inline="always")
def _deg_between(a0, a1, a2, b0, b1, b2):
    """Angle (deg) between unit vectors a and b: atan2(|a x b|, a . b)."""
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    return math.degrees(math.atan2(math.sqrt(c0 * c0 + c1 * c1 + c2 * c2), a0 * b0 + a1 * b1 + a2 * b2))


@njit(cache=True, error_model="numpy")
def _arc_deg(g0, g1, g2, a0, a1, a2, b0, b1, b2):
    """Shortest angle (deg) from the unit direction g to the great-circle arc a-b (unit directions): to
    the arc's plane where g's projection falls between a and b, else to the nearer end."""
    n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    d = max(nn, 1e-300)
    n0, n1, n2 = n0 / d, n1 / d, n2 / d
    ng = n0 * g0 + n1 * g1 + n2 * g2
    q0, q1, q2 = g0 - ng * n0, g1 - ng * n1, g2 - ng * n2
    qd = max(math.sqrt(q0 * q0 + q1 * q1 + q2 * q2), 1e-300)
    q0, q1, q2 = q0 / qd, q1 / qd, q2 / qd
    s1 = (a1 * q2 - a2 * q1) * n0 + (a2 * q0 - a0 * q2) * n1 + (a0 * q1 - a1 * q0) * n2
    s2 = (q1 * b2 - q2 * b1) * n0 + (q2 * b0 - q0 * b2) * n1 + (q0 * b1 - q1 * b0) * n2
    ends = min(_deg_between(a0, a1, a2, g0, g1, g2), _deg_between(b0, b1, b2, g0, g1, g2))
    if (s1 >= 0) & (s2 >= 0) & (nn > 1e-12):
        return min(math.degrees(math.asin(min(max(abs(ng), 0.0), 1.0))), ends)
    return ends


@njit(cache=True, error_model="numpy")
def _unit_dirs(X, Y, Z, eye, R, U):
    """Unit directions (U, 3) float64 of the points (X, Y, Z) (U,) from ``eye`` rotated by ``R`` into U."""
    for k in range(len(X)):
        dx, dy, dz = X[k] - eye[0], Y[k] - eye[1], Z[k] - eye[2]
        u0 = R[0, 0] * dx + R[0, 1] * dy + R[0, 2] * dz
        u1 = R[1, 0] * dx + R[1, 1] * dy + R[1, 2] * dz
        u2 = R[2, 0] * dx + R[2, 1] * dy + R[2, 2] * dz
        inv = 1.0 / max(math.sqrt(u0 * u0 + u1 * u1 + u2 * u2), 1e-300)
        U[k, 0], U[k, 1], U[k, 2] = u0 * inv, u1 * inv, u2 * inv


@njit(cache=True, error_model="numpy")
def exact_terms(X, Y, Z, inv, eye, R, g, eyes, turns, periphery, measured, scale):
    """The float64 terms of the size test for squares given by their corners: ``X``, ``Y``, ``Z`` (U,) m the
    grid nodes, ``inv`` (4, K) each square's corners NW, NE, SE, SW among them; ``eye`` (3,), ``R`` (3, 3)
    the camera, ``g`` (3,) the unit gaze (camera axes); ``eyes`` (m, 3) / ``turns`` (m, 3, 3) the previous
    cameras' eyes and rotations (``measured``: the velocity from them), ``scale`` 1 / (m dt) (1/s).

    Returns (ext, e, v), each (K,) float64: the extent (deg: the largest angle between two corners), the
    eccentricity (deg: 0 with the gaze inside the square, else the least angle to its edge arcs; 0
    without ``periphery``), and the retinal velocity (deg/s: per corner the mean angle moved per step,
    least over the corners; 0 unless ``measured``). One square at a time."""
    n = len(X)
    U = np.empty((n, 3))
    _unit_dirs(X, Y, Z, eye, R, U)
    vel = np.zeros(n)
    if measured:
        prev = U.copy()
        D = np.empty((n, 3))
        for k in range(len(eyes)):
            _unit_dirs(X, Y, Z, eyes[k], turns[k], D)
            for t in range(n):  # atan2, not acos of the dot product: exact 0 for a still corner, and
                # no rounding noise of ~1e-6 deg near 0 that a short time step would make a velocity
                vel[t] += _deg_between(prev[t, 0], prev[t, 1], prev[t, 2], D[t, 0], D[t, 1], D[t, 2])
            prev, D = D, prev
        for t in range(n):
            vel[t] = vel[t] * scale
    K = inv.shape[1]
    ext, ecc, v = np.empty(K), np.zeros(K), np.empty(K)
    g0, g1, g2 = g[0], g[1], g[2]
    for s in range(K):
        a, b, c, d = inv[0, s], inv[1, s], inv[2, s], inv[3, s]
        cmin = 2.0
        near = 1e300
        for p, q in ((a, b), (b, c), (c, d), (d, a), (a, c), (b, d)):  # four edges, two diagonals
            cmin = min(cmin, U[p, 0] * U[q, 0] + U[p, 1] * U[q, 1] + U[p, 2] * U[q, 2])
        ext[s] = math.degrees(math.acos(min(max(cmin, -1.0), 1.0)))
        v[s] = min(min(vel[a], vel[b]), min(vel[c], vel[d]))
        if not periphery:
            continue
        inside = True
        pos = neg = True
        for p, q in ((a, b), (b, c), (c, d), (d, a)):
            gp = g0 * U[p, 0] + g1 * U[p, 1] + g2 * U[p, 2]
            near = min(near, math.degrees(math.acos(min(max(gp, -1.0), 1.0))))
            side = (g0 * (U[p, 1] * U[q, 2] - U[p, 2] * U[q, 1]) + g1 * (U[p, 2] * U[q, 0] - U[p, 0] * U[q, 2])
                    + g2 * (U[p, 0] * U[q, 1] - U[p, 1] * U[q, 0]))
            pos &= side >= 0
            neg &= side <= 0
            inside &= gp > 0
        # the gaze can lie inside only where the nearest corner is within the extent
        if (pos | neg) & inside & (near <= ext[s] * (1.0 + 1e-9) + 1e-12):
            continue
        e = 1e300
        for p, q in ((a, b), (b, c), (c, d), (d, a)):
            e = min(e, _arc_deg(g0, g1, g2, U[p, 0], U[p, 1], U[p, 2], U[q, 0], U[q, 1], U[q, 2]))
        ecc[s] = e
    return ext, ecc, v
