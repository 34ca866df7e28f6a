"""Single-harmonic balance and its frequency response, against independent closed forms."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.optimize import brentq

from perturb import ModelError, ParameterError, builtin_model
from perturb.methods.harmonic_balance import single_harmonic_balance
from perturb.numeric.amplitude import approximation_response


def nsd_amplitude_equation(A, W, k, mu, F):
    """Zou–Nagarajaiah eqs. (54)-(55) with the phase eliminated, written out separately:
    (W^2 - k)A - (1-k)(A(a0 + a2) - 2a1) = -F cos(phi), mu W A = F sin(phi),
    a_n = 2 sin(n theta)/(n pi), a0 = 2 theta/pi, theta = arccos(1/A) (zero for A <= 1)."""
    A = np.asarray(A, float)
    theta = np.arccos(np.minimum(1.0, 1.0 / A))
    a0, a1, a2 = 2 * theta / np.pi, 2 * np.sin(theta) / np.pi, np.sin(2 * theta) / np.pi
    cos_part = (W**2 - k) * A - (1 - k) * (A * (a0 + a2) - 2 * a1)
    return cos_part**2 + (mu * W * A) ** 2 - F**2


@pytest.fixture(scope="module")
def nsd_response():
    osc = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0)
    return approximation_response(single_harmonic_balance(osc), (0.2, 2.0), points=1500)


def test_every_point_satisfies_the_papers_first_order_equations(nsd_response):
    assert nsd_response.branches
    for br in nsd_response.branches:
        res = nsd_amplitude_equation(br.first_harmonic_amplitude, br.omega, -2.0, 0.05, 2.0)
        assert np.max(np.abs(res)) / 4.0 < 1e-9


def test_no_branch_is_missed(nsd_response):
    # brute force: all roots A of the amplitude equation at fixed Omega, by a fine scan
    grid = np.geomspace(1e-3, 200, 40001)
    for W in (0.3, 0.6, 0.9, 0.95, 1.2, 1.8):
        f = nsd_amplitude_equation(grid, W, -2.0, 0.05, 2.0)
        idx = np.nonzero(np.sign(f[:-1]) * np.sign(f[1:]) < 0)[0]
        roots = [
            brentq(nsd_amplitude_equation, grid[i], grid[i + 1], args=(W, -2.0, 0.05, 2.0))
            for i in idx
        ]
        assert roots, W
        for root in roots:
            # some branch passes through (W, root)
            best = np.inf
            for br in nsd_response.branches:
                w, a = br.omega, br.first_harmonic_amplitude
                s = np.nonzero(np.sign(w[:-1] - W) * np.sign(w[1:] - W) <= 0)[0]
                for j in s:
                    t = 0.0 if w[j + 1] == w[j] else (W - w[j]) / (w[j + 1] - w[j])
                    best = min(best, abs(a[j] + t * (a[j + 1] - a[j]) - root) / root)
            assert best < 2e-3, (W, root, best)


def test_branch_inside_the_negative_stiffness_well_is_unstable(nsd_response):
    # |x| < 1 on that branch: a linear oscillator with stiffness k = -2 (a saddle), unstable
    # for every forcing; the paper computes this branch exactly and reports it unstable.
    small = [br for br in nsd_response.branches if br.amplitude.max() < 1]
    assert small
    for br in small:
        assert not br.stable.any()
        lam = -0.025 + np.sqrt(0.025**2 + 2.0)  # growth rate of x'' + 0.05x' - 2x = 0
        expected = np.exp(lam * 2 * np.pi / br.omega)
        np.testing.assert_allclose(br.max_multiplier, expected, rtol=1e-6)


def test_linear_oscillator_multipliers_are_exact():
    # k = 1 makes nsd linear: x'' + mu x' + x = F cos(Omega t)
    osc = builtin_model("nsd", k=1.0, mu=0.1, F=0.5)
    resp = approximation_response(single_harmonic_balance(osc), (0.3, 3.0), points=200)
    assert len(resp.branches) == 1
    br = resp.branches[0]
    W = br.omega
    np.testing.assert_allclose(
        br.amplitude, 0.5 / np.sqrt((1 - W**2) ** 2 + (0.1 * W) ** 2), rtol=1e-9
    )
    np.testing.assert_allclose(br.max_multiplier, np.exp(-0.05 * 2 * np.pi / W), rtol=1e-9)
    assert br.stable.all()
    np.testing.assert_allclose(br.mean, 0, atol=1e-12)


def test_duffing_backbone_form_and_jump():
    osc = builtin_model("duffing", mu=0.1, omega0=1.0, alpha=1.0, F=0.5)
    resp = approximation_response(single_harmonic_balance(osc), (0.5, 2.5), points=1500)
    for br in resp.branches:
        A, W = br.first_harmonic_amplitude, br.omega
        res = ((W**2 - 1 - 0.75 * A**2) * A) ** 2 + (0.1 * W * A) ** 2 - 0.25
        assert np.max(np.abs(res)) < 1e-9
    # hardening: two folds (jump up and jump down), the middle branch unstable between them
    assert len(resp.folds) == 2
    lo, hi = sorted(w for w, _ in resp.folds)
    assert 1.0 < lo < hi
    mid = 0.5 * (lo + hi)
    found = []  # (amplitude, stable) of every solution at Omega = mid
    for br in resp.branches:
        w = br.omega
        for j in np.nonzero(np.sign(w[:-1] - mid) * np.sign(w[1:] - mid) <= 0)[0]:
            found.append((br.amplitude[j], bool(br.stable[j])))
    found.sort()
    assert len(found) == 3
    assert [st for _, st in found] == [True, False, True]


def test_bad_requests_are_clear_errors():
    osc = builtin_model("nsd")
    approx = single_harmonic_balance(osc)
    with pytest.raises(ParameterError, match="omega_range"):
        approximation_response(approx, (2.0, 0.2))
    with pytest.raises(ParameterError, match="omega_range"):
        approximation_response(approx, (0.0, float("nan")))
    with pytest.raises(ParameterError, match="needs values for mu"):
        approximation_response(single_harmonic_balance(osc.with_params(mu=None)), (0.2, 2))
    with pytest.raises(ModelError, match="not odd"):
        single_harmonic_balance(builtin_model("clearance"))
    with pytest.raises(ModelError, match="covers"):
        single_harmonic_balance(builtin_model("vanderpol"))


def test_hill_stability_changes_exactly_at_the_folds():
    """Hill's method truncated at the solution's harmonic changes stability where the
    harmonic-balance branch turns (a saddle-node), unlike Floquet about the approximate orbit
    with all harmonics, which on this strongly nonlinear Duffing case turns far from it."""
    osc = builtin_model("duffing", mu=0.1, omega0=1.0, alpha=1.0, F=0.5)
    approx = single_harmonic_balance(osc)
    resp = approximation_response(approx, (0.5, 2.5), points=3000)
    (br,) = resp.branches
    flips = np.nonzero(np.diff(br.stable.astype(int)))[0]
    assert len(flips) == 2 == len(resp.folds)
    for (w_fold, a_fold), j in zip(
        sorted(resp.folds), sorted(flips, key=lambda j: br.omega[j]), strict=True
    ):
        assert abs(br.omega[j] - w_fold) < 1e-3
        assert abs(br.first_harmonic_amplitude[j] - a_fold) / a_fold < 1e-2
    floquet = approximation_response(approx, (0.5, 2.5), points=3000, stability="floquet")
    assert not np.array_equal(floquet.branches[0].stable, br.stable)


def test_vectorised_bracketed_roots_match_scalar_brentq():
    """The all-brackets-at-once root refinement (regula falsi / Illinois with bisection
    safeguard) against scipy's scalar brentq, one bracket at a time, on functions with
    simple, steep, flat (cubic) and exactly representable roots."""
    from perturb.numeric.amplitude import bracketed_roots

    shifts = np.array([0.3, 1.7, 2.5, 1e-3, 4.0])
    funcs = [
        lambda x, s: np.tanh(50 * (x - s)),
        lambda x, s: (x - s) ** 3,
        lambda x, s: np.exp(x) - np.exp(s),
        lambda x, s: x - s,
        lambda x, s: np.sin(x - s) + 0.5 * (x - s),
    ]
    for g in funcs:
        a, b = shifts - 0.29, shifts + 0.61

        def f(x, idx, g=g):
            return g(x, shifts[idx])

        lo, hi, _, _ = bracketed_roots(f, a, b, f(a, np.arange(5)), f(b, np.arange(5)))
        for i, s in enumerate(shifts):
            ref = brentq(lambda x, i=i, g=g: g(x, shifts[i]), a[i], b[i], xtol=1e-16, maxiter=2000)
            assert lo[i] <= hi[i]
            assert abs(0.5 * (lo[i] + hi[i]) - ref) <= 8e-15 * max(1.0, abs(ref)), (g, s)


def test_safeguarded_newton_matches_brentq():
    from perturb.numeric.amplitude import safe_newton

    # exp(x) + 0.2 sin(4 (x - s)) is increasing for x > log(0.8): one root per bracket
    s = np.array([0.9, 1.4, 2.2, 3.0])
    lo, hi = s - 0.5, s + 0.3

    def fdf(x, idx):
        d = x - s[idx]
        return np.exp(x) - np.exp(s[idx]) + 0.2 * np.sin(4 * d), np.exp(x) + 0.8 * np.cos(4 * d)

    f_lo, f_hi = fdf(lo, np.arange(4))[0], fdf(hi, np.arange(4))[0]
    ok = f_lo * f_hi < 0
    x = safe_newton(fdf, lo[ok], hi[ok], f_lo[ok], f_hi[ok], 0.5 * (lo + hi)[ok], 1e-14)
    idx = np.nonzero(ok)[0]
    assert idx.size == 4
    for k, i in enumerate(idx):

        def f(t, i=i):
            return fdf(np.array([t]), np.array([i]))[0][0]

        ref = brentq(f, lo[i], hi[i], xtol=1e-15)
        assert abs(x[k] - ref) < 1e-12


def test_critical_points_give_max_abs_of_trigonometric_polynomials():
    """max |x| from the critical points (first-harmonic-dominated rows by the bracketing
    argument, the others by sampling) against brute force on 2**16 samples plus a scalar
    bounded minimiser; rows include a pure cosine, strong higher harmonics and a mean."""
    from scipy.optimize import minimize_scalar

    from perturb.numeric.amplitude import critical_points, max_abs_at

    rng = np.random.default_rng(5)
    n_rows, K = 40, 16
    C = rng.normal(size=(n_rows, K)) * np.exp(-0.4 * np.arange(K))
    S = rng.normal(size=(n_rows, K)) * np.exp(-0.4 * np.arange(K))
    C[:10, 2:] *= 1e-3  # first harmonic dominates
    C[10:20, 1] = 0.05  # higher harmonics dominate
    C[20, :], S[20, :] = 0, 0
    C[20, 1] = 2.0  # a pure cosine: max |x| = 2
    C[21, 0] = 5.0  # a mean
    rows, tau, xe = critical_points(C, S)
    got = max_abs_at(rows, xe, n_rows, C[:, 0])
    t = np.linspace(0, 2 * np.pi, 1 << 16, endpoint=False)
    n = np.arange(K)
    for i in range(n_rows):

        def x(s, i=i):
            return np.sum(C[i] * np.cos(n * s) + S[i] * np.sin(n * s))

        xs = C[i] @ np.cos(np.outer(n, t)) + S[i] @ np.sin(np.outer(n, t))
        j = int(np.argmax(np.abs(xs)))
        sign = np.sign(xs[j])
        res = minimize_scalar(
            lambda s, i=i, sign=sign: -sign * x(s),
            bounds=(t[j] - 1e-3, t[j] + 1e-3),
            method="bounded",
            options={"xatol": 1e-12},
        )
        ref = max(abs(xs[j]), abs(res.fun))
        assert abs(got[i] - ref) <= 1e-12 * ref, i
    assert abs(got[20] - 2.0) < 1e-15


@pytest.mark.parametrize("k", [-3.0, -0.5])
def test_exact_pwl_hill_matches_sampled_hill_exponents(k):
    """Hill's method with the stiffness's Fourier coefficients from the exact crossing instants
    (the fast path of frequency_response) against floquet.hill_exponents, which integrates
    them over the orbit sampled at N instants with a cubic crossing estimate; the latter
    converges to the former as N grows."""
    from perturb.methods import modified_lindstedt
    from perturb.numeric.amplitude import Waveform, compile_response
    from perturb.numeric.stability import hill_exponents

    osc = builtin_model("nsd", k=k, mu=0.05, F=2.0)
    approx = modified_lindstedt(osc, 1)
    cp = compile_response(approx)
    assert cp.hill is not None
    resp = approximation_response(cp, (0.3, 2.0), points=200)
    w = np.concatenate([br.omega for br in resp.branches])[::7]
    A = np.concatenate([br.first_harmonic_amplitude for br in resp.branches])[::7]
    pc, ps = cp.phase_u(cp.atoms.evaluate(A, cp.phase_u.rows), A, w)
    phi = np.arctan2(ps, pc)
    wave = Waveform(approx, cp.A, cp.phase, cp.Omega)
    coefs = wave.coefficients(A, phi, w)
    from perturb.numeric.amplitude import critical_points

    fast = cp.hill.max_multiplier(coefs, critical_points(*coefs), w)
    xf, dxf = wave.samples(A, phi, w, 8192, coefs)
    lam = hill_exponents(osc, xf, w[:, None] * dxf, 2 * np.pi / w, 1, cp.Omega)
    sampled = np.exp(np.max(lam.real, axis=1) * 2 * np.pi / w)
    np.testing.assert_allclose(fast, sampled, rtol=1e-7)


def _response_arrays(resp):
    return [
        np.concatenate([np.asarray(getattr(b, f), float) for b in resp.branches])
        for f in ("omega", "amplitude", "first_harmonic_amplitude", "mean", "max_multiplier")
    ]


@pytest.mark.parametrize("stability", ["slow_flow", "hill"])
def test_unchecked_fourier_path_gives_the_checked_response_bitwise(stability):
    # the compiled solver evaluates the amplitude's Fourier atoms with fourier's unchecked
    # kernels; the validating public ones must give the very same response
    from perturb.methods import modified_lindstedt
    from perturb.numeric.amplitude import compile_response

    osc = builtin_model("nsd", k=-3.0, mu=0.05, F=2.0)
    solver = compile_response(modified_lindstedt(osc, 1))
    assert solver.atoms.unchecked
    fast = approximation_response(solver, (0.2, 2.0), points=600, stability=stability)
    solver.atoms.unchecked = False  # also drops the plans built with the unchecked kernels
    slow = approximation_response(solver, (0.2, 2.0), points=600, stability=stability)
    assert fast.folds == slow.folds
    for x, y in zip(_response_arrays(fast), _response_arrays(slow), strict=True):
        np.testing.assert_array_equal(x, y)


def test_closed_form_hill_exponents_match_lapack():
    from perturb.numeric.amplitude import hill1_exponents, hill1_matrix

    rng = np.random.default_rng(5)
    n = 2000
    w = 10 ** rng.uniform(-1, 0.5, n)
    q0 = rng.normal(0, 2, n)
    # harmonics of q from absent to O(1), so that real, complex and clustered roots all occur
    qk = rng.normal(0, 1, (4, n)) * rng.choice([0.0, 1e-8, 1.0], (4, n))
    scale = np.sqrt(1 + w**2 + np.abs(q0) + np.abs(qk).sum(axis=0))

    def exponent(z):
        # the stability measure: largest real part of the two exponents of least |Im|
        order = np.argsort(np.abs(z.imag) + 1e-12 * np.abs(z.real), axis=1)
        return np.max(np.take_along_axis(z, order[:, :2], axis=1).real, axis=1)

    # (p > 0: with p = 0 the selection itself is ambiguous, +-nu having equal |Im| and |Re|)
    for p in (0.01, 0.05, 0.7):
        lam = hill1_exponents(q0, *qk, w, p)
        ref = np.linalg.eigvals(hill1_matrix(q0, *qk, w, p))
        # the same six eigenvalues (greedy nearest matching), to LAPACK's own accuracy:
        # ~1e-15 typically, ~eps**(1/3) where three roots cluster
        for i in range(n):
            rest = list(ref[i])
            for z in lam[i]:
                j = int(np.argmin(np.abs(np.array(rest) - z)))
                assert abs(rest.pop(j) - z) < 1e-9 * scale[i]
        # where two pairs have the same |Im| (+-nu complex) LAPACK's rounding noise in Im
        # outweighs the 1e-12 |Re| tie-break, and its pick is arbitrary: compare elsewhere
        im = np.sort(np.abs(ref.imag), axis=1)
        clear = im[:, 2] - im[:, 1] > 1e-9 * scale
        assert clear.mean() > 0.75
        diff = np.abs(exponent(lam) - exponent(ref)) / scale
        assert np.max(diff[clear]) < 1e-10


@functools.lru_cache(maxsize=4)
def _dense_tables(K, count, endpoint):
    """cos(n t), sin(n t) at ``count`` equally spaced t over one period, n < K."""
    t = np.linspace(0, 2 * np.pi, count, endpoint=endpoint)
    n = np.arange(K)
    return t, np.cos(np.outer(t, n)), np.sin(np.outer(t, n))


def _oracle_max_abs(c, s):
    """max |x| of one row ``x = sum_n c_n cos(n t) + s_n sin(n t)`` by brute force: 1e5
    samples, then a bounded scalar maximisation about the best one (independent of
    :func:`critical_points`'s brackets, Newton steps and symmetry shortcuts)."""
    from scipy.optimize import minimize_scalar

    n = np.arange(c.size)

    def x(t):
        return float(np.sum(c * np.cos(n * t) + s * np.sin(n * t)))

    t, ct, st = _dense_tables(c.size, 100_000, False)
    xs = ct @ c + st @ s
    j = int(np.argmax(np.abs(xs)))
    sign = np.sign(xs[j])
    h = 2 * np.pi / t.size
    res = minimize_scalar(
        lambda u: -sign * x(u),
        bounds=(t[j] - h, t[j] + h),
        method="bounded",
        options={"xatol": 1e-13},
    )
    return max(abs(xs[j]), abs(res.fun))


def _symmetric_rows():
    """Half-wave symmetric rows (odd harmonics only, as the nsd waveforms): first-harmonic
    dominated, dominated by higher harmonics (sampled brackets), flat maxima (``x'' = 0``
    or ``x'' = x'''' = 0`` at the top) and a pure cosine."""
    rng = np.random.default_rng(11)
    K = 16
    C, S = np.zeros((30, K)), np.zeros((30, K))
    decay = np.exp(-0.3 * np.arange(1, K, 2))
    C[:, 1::2] = rng.normal(size=(30, K // 2)) * decay
    S[:, 1::2] = rng.normal(size=(30, K // 2)) * decay
    C[:8, 3::2] *= 1e-3  # first harmonic dominates
    C[8:16, 1] = 0.02  # higher harmonics dominate
    S[8:16, 1] = 0.0
    C[16:20], S[16:20] = 0.0, 0.0
    C[16, 1], C[16, 3] = 1.0, -1 / 9  # flat top: x''(0) = 0, x ~ 8/9 - t^4 / 3
    C[17, 1], C[17, 3], C[17, 5] = 1.0, -5 / 32, 1 / 160  # x'' = x'''' = 0 at t = 0
    C[18, 1] = 2.5  # pure cosine
    C[19, 1], S[19, 3] = 0.7, 0.3  # rotated peaks
    return C, S


@pytest.mark.parametrize("count", [128, 127])
def test_max_abs_of_half_wave_symmetric_rows_matches_dense_oracle(count):
    """max |x| from :func:`critical_points` (which refines the critical points in [0, pi) of a
    half-wave symmetric row and mirrors the rest, and orders them by one argsort) against
    brute force; an odd sample count takes the path without mirroring of sampled rows."""
    from perturb.numeric.amplitude import critical_points, max_abs_at

    C, S = _symmetric_rows()
    rows, tau, xe = critical_points(C, S, count)
    got = max_abs_at(rows, xe, C.shape[0], C[:, 0])
    for i in range(C.shape[0]):
        ref = _oracle_max_abs(C[i], S[i])
        assert abs(got[i] - ref) <= 1e-12 * ref, (i, got[i], ref)
        # ordered by row, then tau in [0, 2 pi), and critical: x'(tau) = 0
        t = tau[rows == i]
        assert np.all(np.diff(t) > 0) and t.min() >= 0 and t.max() < 2 * np.pi
    assert np.all(np.diff(rows) >= 0)
    assert abs(got[18] - 2.5) < 1e-15


@functools.lru_cache(maxsize=2)
def _nsd_orbits(k, F, grazing=(1e-2, 1e-4, 1e-6)):
    """Waveform coefficients of the first-order mLP response of nsd (every 23rd point and
    the orbits with max |x| closest above 1), plus the orbits of the response rescaled so
    that max |x| = 1 + eps for each ``eps`` in ``grazing``: near-double crossings. Returns
    the solver, ``C, S``, the response's amplitudes of the unscaled rows and the number of
    rescaled rows (last)."""
    from perturb.methods import modified_lindstedt
    from perturb.numeric.amplitude import compile_response

    osc = builtin_model("nsd", k=k, mu=0.05, F=F)
    cp = compile_response(modified_lindstedt(osc, 1))
    resp = approximation_response(cp, (0.2, 2.0), points=2000)
    w = np.concatenate([br.omega for br in resp.branches])
    A = np.concatenate([br.first_harmonic_amplitude for br in resp.branches])
    amp = np.concatenate([br.amplitude for br in resp.branches])
    pc, ps = cp.phase_u(cp.atoms.evaluate(A, cp.phase_u.rows), A, w)
    C, S = cp.wave.coefficients(A, np.arctan2(ps, pc), w)
    above = np.nonzero(amp > 1)[0]
    near = above[np.argsort(amp[above])[:5]]
    pick = np.unique(np.concatenate([np.arange(0, w.size, 23), near]))
    # rescaled: the waveforms of the largest orbits (strongly non-sinusoidal) and of some
    # inside the well; max |x| from the dense oracle, so the target 1 + eps is exact to ~1e-16
    shapes = np.concatenate(
        [np.argsort(amp)[-3:], np.nonzero(amp < 1)[0][:: max(1, (amp < 1).sum() // 3)]]
    )
    Cg, Sg = [], []
    for i in shapes:
        m = _oracle_max_abs(C[i], S[i])
        for eps in grazing:
            Cg.append(C[i] * (1 + eps) / m)
            Sg.append(S[i] * (1 + eps) / m)
    return cp, np.vstack([C[pick], Cg]), np.vstack([S[pick], Sg]), amp[pick], len(Cg)


@pytest.mark.parametrize(("k", "F"), [(-3.0, 2.0), (-0.5, 2.0)])
def test_response_amplitudes_match_dense_oracle_including_grazing(k, F):
    """The amplitude column (max |x| over a period) of the first-order mLP response of nsd
    against brute force on the waveform, including the orbits of the response closest above
    the breakpoints (max |x| = 1.0024 for k = -0.5) and rescaled orbits with
    max |x| = 1 + 1e-2 .. 1e-6."""
    from perturb.numeric.amplitude import critical_points, max_abs_at

    cp, C, S, amp, _ = _nsd_orbits(k, F)
    rows, _, xe = critical_points(C, S)
    got = max_abs_at(rows, xe, C.shape[0], C[:, 0])
    for i in range(C.shape[0]):
        ref = _oracle_max_abs(C[i], S[i])
        assert abs(got[i] - ref) <= 1e-12 * ref, (i, got[i], ref)
        if i < amp.size:  # the response's own column (coefficients from the atoms' path)
            assert abs(amp[i] - ref) <= 1e-12 * ref, (i, amp[i], ref)


@pytest.mark.parametrize(("k", "F"), [(-3.0, 2.0), (-0.5, 2.0)])
def test_breakpoint_crossings_match_brentq_including_grazing(k, F):
    """The crossings of the breakpoints +-1 (found for d = +1 and mirrored to -1 on these
    half-wave symmetric orbits, from a half-cosine guess by Halley steps) against brentq on
    the sign changes of 1e5 samples of x - d, with orbits that graze the breakpoints
    (max |x| = 1 + 1e-6: crossings 1e-3 apart)."""
    from scipy.optimize import brentq

    from perturb.numeric.amplitude import critical_points

    cp, C, S, _, n_grazing = _nsd_orbits(k, F)
    rows, tau, jump = cp.hill.crossings(C, S, *critical_points(C, S))
    n = np.arange(C.shape[1])
    t, ct, st = _dense_tables(C.shape[1], 100_001, True)
    # q = g'(x) jumps by k - 1 crossing -1 upwards and by 1 - k crossing +1 upwards
    levels = ((-1.0, k - 1.0), (1.0, 1.0 - k))
    for i in range(C.shape[0]):

        def x(u, i=i):
            return float(np.sum(C[i] * np.cos(n * u) + S[i] * np.sin(n * u)))

        xs = ct @ C[i] + st @ S[i]
        ref = []
        for d, dq in levels:
            for j in np.nonzero(np.sign(xs[:-1] - d) * np.sign(xs[1:] - d) < 0)[0]:
                r = brentq(lambda u, d=d: x(u) - d, t[j], t[j + 1], xtol=1e-15, rtol=1e-15)
                ref.append((np.mod(r, 2 * np.pi), dq if xs[j + 1] > xs[j] else -dq))
        ref.sort()
        if i >= C.shape[0] - n_grazing:  # rescaled to max |x| = 1 + eps: near-double crossings
            assert len(ref) >= 2, i
        mine = np.argsort(tau[rows == i])
        assert mine.size == len(ref), i
        np.testing.assert_allclose(tau[rows == i][mine], [r[0] for r in ref], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(jump[rows == i][mine], [r[1] for r in ref])


def test_old_name_warns_and_answers_the_same():
    # perturb.frequency_response takes an oscillator; the approximation tracer has its own name
    import perturb.numeric.amplitude as fr

    approx = single_harmonic_balance(builtin_model("nsd", k=-2.0))
    with pytest.warns(DeprecationWarning, match="approximation_response"):
        old = fr.frequency_response(approx, (0.5, 1.5), points=200)
    new = approximation_response(approx, (0.5, 1.5), points=200)
    assert [b.amplitude.tolist() for b in old.branches] == [
        b.amplitude.tolist() for b in new.branches
    ]
    assert "frequency_response" not in fr.__all__


# ---------------------------------------------------------------- free parameters --
def _free_nsd(method):
    from perturb.model.parsing import real_symbol

    osc = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0).with_params({"mu": None, "k": None})
    return method(osc), [real_symbol("mu"), real_symbol("k")]


@pytest.mark.parametrize(("mu", "k"), [(0.05, -2.0), (0.2, -0.5), (0.1, 1.5)])
def test_solver_with_free_parameters_finds_the_papers_roots(mu, k):
    # compiled once with mu and k free (the sweep's case), evaluated at given values: every
    # root at each frequency against the paper's amplitude equation, solved by brentq on a
    # dense scan of its own
    from perturb.numeric.amplitude import compile_response

    approx, syms = _free_nsd(single_harmonic_balance)
    solver = compile_response(approx, "slow_flow", parameters=syms)
    omegas = np.linspace(0.3, 1.9, 9)
    iw, roots = solver.roots_at(omegas, mu, k)
    grid = np.geomspace(1e-3, 1e3, 20001)
    for j, w in enumerate(omegas):
        f = functools.partial(nsd_amplitude_equation, W=w, k=k, mu=mu, F=2.0)
        v = f(grid)
        sc = np.nonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0)[0]
        want = [brentq(f, grid[i], grid[i + 1], xtol=1e-14, rtol=1e-14) for i in sc]
        got = np.sort(roots[iw == j])
        assert got.size == len(want)
        np.testing.assert_allclose(got, want, rtol=1e-10)


def test_solver_with_free_parameters_extremes_match_dense_samples():
    # min/max of x over a period at the waveform's critical points, against 20000 samples of
    # the waveform expression itself (sampling error ~ A (pi / 20000)^2 / 2)
    import sympy as sp

    from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS
    from perturb.methods import modified_lindstedt
    from perturb.numeric.amplitude import compile_response

    approx, syms = _free_nsd(lambda osc: modified_lindstedt(osc, 1))
    solver = compile_response(approx, "slow_flow", parameters=syms)
    mu, k = 0.1, -1.0
    a = np.array([0.5, 1.5, 3.0, 8.0])
    w = np.array([0.4, 0.9, 1.2, 0.95])
    lo, hi = solver.extremes(a, w, mu, k)
    phi = solver.phases(a, w, mu, k)
    keep = {*syms, approx.frequency}
    values = {s: v for s, v in approx.oscillator.substitutions().items() if s not in keep}
    wave = sp.sympify(approx.waveform).xreplace(values | {syms[0]: mu, syms[1]: k})
    args = (approx.tau, approx.amplitude, approx.unknowns[1], approx.frequency)
    fn = sp.lambdify(args, wave, modules=[NUMERIC_IMPLEMENTATIONS, "numpy"])
    tau = np.linspace(0, 2 * np.pi, 20000, endpoint=False)
    for i in range(a.size):
        xs = np.broadcast_to(fn(tau, a[i], phi[i], w[i]), tau.shape)
        scale = np.max(np.abs(xs))
        assert lo[i] <= xs.min() + 1e-12 * scale and hi[i] >= xs.max() - 1e-12 * scale
        np.testing.assert_allclose([lo[i], hi[i]], [xs.min(), xs.max()], rtol=0, atol=1e-7 * scale)


def test_solver_with_free_parameters_does_not_trace():
    from perturb.numeric.amplitude import compile_response, solutions_at

    approx, syms = _free_nsd(single_harmonic_balance)
    solver = compile_response(approx, "slow_flow", parameters=syms)
    with pytest.raises(ParameterError, match="free parameters"):
        approximation_response(solver, (0.2, 2.0))
    with pytest.raises(ParameterError, match="free parameters"):
        solutions_at(solver, [1.0])


def test_extremes_of_a_waveform_that_is_no_trigonometric_polynomial():
    # a waveform not linear in cos/sin(n tau + c) takes the sampled path with Newton
    # polishing (samples alone would be low by ~1e-4 here); the oracle is the closed form:
    # x = A exp(cos(tau + phi)) has max A e and min A / e
    import dataclasses

    import sympy as sp

    from perturb.numeric.amplitude import Waveform

    approx = single_harmonic_balance(builtin_model("nsd", k=-2.0, mu=0.05, F=2.0))
    A, phase, tau = approx.amplitude, approx.unknowns[1], approx.tau
    odd = dataclasses.replace(approx, waveform=A * sp.exp(sp.cos(tau + phase)))
    wave = Waveform(odd, A, phase, approx.frequency)
    assert wave.terms is None
    a = np.array([0.5, 2.0, 7.0])
    lo, hi = wave.extremes(a, np.array([0.3, -1.0, 2.5]), np.ones(3))
    np.testing.assert_allclose(hi, a * np.e, rtol=1e-14)
    np.testing.assert_allclose(lo, a / np.e, rtol=1e-14)
