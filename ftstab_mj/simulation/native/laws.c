/* The C twins of the registered control laws (ftstab_mj/control/laws/), see laws.h.
 *
 * The paper's laws take powers as NumPy arrays do (abs_pow: the sqrt and square fast paths, as the
 * ideal chain and the tests evaluate them on batches); the field's laws as NumPy scalars do
 * (scalar_pow: libm's pow), as the run loop's Python path evaluates them. With the NumPy code's
 * operations in its order, a twin then gives the same doubles, except where the NumPy code sums
 * through a BLAS dot product (a surface of r > 2 coefficients, linear's K z and P z): one rounding
 * of the sum may differ.
 */
#include "laws.h"

#include <stddef.h>

/* ---- the paper's laws on Hong's controller (control/hong.py, control/laws/paper.py) ------------- */

/* Hong's controller at one state z (r,): u0, V1, dV1/dz_r and v_{r-1}, the virtual control the last
 * integrator follows (hong.py HongController.evaluate, _chain).
 * |a|^(b+1) in W is computed as |a|^b * |a| from the |a|^b the recursion already has (3 pow calls less
 * per sample at r = 2), and so is it in hong.py's _W: the same V1, bit for bit. */
static void hong_eval(const ft_law *L, const double *z, double *u0, double *V1, double *dV, double *vlast) {
    const int r = L->r;
    double v = 0.0;          /* v_i */
    double pv = 0.0;         /* |v_i|^beta_i (full form) */
    double V = 0.0;
    double dv = 0.0;
    for (int i = 0; i < r; i++) {
        const double b = L->beta[i], zi = z[i];
        double s, W;
        if (L->simplified) {
            s = zi - v;
            /* W(z, a, 1) = (|z|^2 - |a|^2)/2 - a (z - a) */
            W = (fabs(zi) * fabs(zi) - fabs(v) * fabs(v)) / 2.0 - (np_sign(v) * fabs(v)) * (zi - v);
            if (i == r - 1) dv = zi - v;
        } else {
            const double pz = abs_pow(zi, b);
            pv = abs_pow(v, b);
            const double sz = np_sign(zi) * pz, sv = np_sign(v) * pv;
            s = sz - sv;
            W = (pz * fabs(zi) - pv * fabs(v)) / (b + 1.0) - sv * (zi - v);
            if (i == r - 1) dv = sz - sv;
        }
        V = V + W;
        if (i == r - 1) *vlast = v;
        v = -L->gains[i] * (np_sign(s) * abs_pow(s, L->expo[i]));
    }
    *u0 = v;
    *V1 = V;
    *dV = dv;
}

/* The paper's law at z (r,) with the adaptive state phi_hat (paper.py *.output). The implicit
 * robust law: w = -clip((sigma + h u0) / (h gamma_m), -P, P), sigma = z_r - v_{r-1}
 * (implicit.py sign_step), u = u0 / gamma_m + w. */
static void paper_eval(const ft_law *L, const double *z, double phi_hat, ft_out *o) {
    double u0, V1, dV, vlast = 0.0;
    hong_eval(L, z, &u0, &V1, &dV, &vlast);
    double g, p;
    if (L->law == FT_ROBUST) {
        g = 1.0 / L->gamma_m;
        p = L->phibar / L->gamma_m;
    } else if (L->law == FT_ADAPTIVE) {
        g = L->kappa + L->delta * fabs(u0);
        p = phi_hat;
    } else {
        g = 1.0;
        p = 0.0;
    }
    if (L->law == FT_NOMINAL) o->u = u0;
    else if (L->law == FT_ROBUST && L->implicit) {
        const double h = L->period, sigma = z[L->r - 1] - vlast;
        o->u = g * u0 + -np_clip((sigma + h * u0) / (h * L->gamma_m), -p, p);
    } else o->u = g * u0 + p * np_sign(u0);
    o->u0 = u0;
    o->V1 = V1;
    o->dV1_dzr = dV;
    o->gamma_hat = g;
    o->phi_hat = p;
}

/* nu_eps(V1) of the adaptive law (paper.py AdaptiveLaw.nu). */
static inline double adaptive_nu(const ft_law *L, double V1) {
    const double x = (fabs(V1) - 0.75 * L->eps) / (0.25 * L->eps);
    return 0.5 + 0.5 * x / np_maximum(1.0, fabs(x));
}

static inline double band_rhs(double a, double b, double y, double eta) {
    return a - b * abs_pow(np_maximum(y, 0.0), eta);
}

/* phi_hat after one period h with V1 held (paper.py advance_phi_hat): exact ramp or finite-time
 * decay outside the transition band of nu, RK4 with L->substeps sub-steps inside it. */
double ft_advance_phi(const ft_law *L, double V1, double phi_hat, double h) {
    if (L->law != FT_ADAPTIVE) return phi_hat + 0.0;
    const double phi = np_maximum(phi_hat, 0.0);
    const double nu = adaptive_nu(L, V1);
    const double eta = L->eta;
    if (nu >= 1.0) return phi + L->rate * h;
    if (!(nu > 0.0 && nu < 1.0)) {
        return abs_pow(np_maximum(0.0, abs_pow(phi, 1.0 - eta) - (1.0 - eta) * h), 1.0 / (1.0 - eta));
    }
    const double a = L->rate * nu, b = 1.0 - nu, dt = h / L->substeps;
    double x = phi;
    for (int s = 0; s < L->substeps; s++) {
        const double k1 = band_rhs(a, b, x, eta);
        const double k2 = band_rhs(a, b, x + 0.5 * dt * k1, eta);
        const double k3 = band_rhs(a, b, x + 0.5 * dt * k2, eta);
        const double k4 = band_rhs(a, b, x + dt * k3, eta);
        x = np_maximum(0.0, x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4));
    }
    return x;
}

/* ---- the field's laws ---------------------------------------------------------------------------
 * Each: its par layout (= its Python class's native_params()), its output, its state's advance.
 *
 * The run loop's Python path evaluates a law on one state z (r,): its powers are then taken of NumPy
 * scalars, which call libm's pow for every exponent (0.5 included: no sqrt fast path), and these
 * twins do the same, so that the two paths give the same doubles (x^1 and x^2 are exact either way). */

/* |a|^p as a NumPy scalar takes it. */
static inline double scalar_pow(double a, double p) {
    const double m = fabs(a);
    if (p == 1.0) return m;
    if (p == 2.0) return m * m;
    return pow(m, p);
}

static inline double scalar_sig(double a, double p) { return np_sign(a) * scalar_pow(a, p); }

/* A LawOutput with only u (and the given gamma_hat, phi_hat; NaN for "not of that form"). */
static inline void only_u(ft_out *o, double u, double gamma_hat, double phi_hat) {
    o->u = u;
    o->u0 = o->V1 = o->dV1_dzr = NAN;
    o->gamma_hat = gamma_hat;
    o->phi_hat = phi_hat;
}

/* Levant's nested controller (levant.py LevantNested.psi), r in 1..4.
 * par: alpha, beta_1..beta_{r-1}, q/(r-i+1) for i = 1..r-1, (r-i)/q for i = 1..r-1. */
static double levant_nested(const ft_law *L, const double *z) {
    const int r = L->r;
    const double *beta = L->par + 1, *e1 = L->par + r, *e2 = L->par + 2 * r - 1;
    double psi = z[0], acc = 0.0;
    for (int i = 1; i < r; i++) {
        acc = acc + scalar_pow(z[i - 1], e1[i - 1]);
        psi = z[i] + beta[i - 1] * scalar_pow(acc, e2[i - 1]) * np_sign(psi);
    }
    return -L->par[0] * np_sign(psi);
}

/* Levant's quasi-continuous controller (levant.py LevantQuasiContinuous.psi), r in 1..4.
 * par: alpha, beta_1..beta_{r-1}, (r-i)/(r-i+1) for i = 1..r-1. */
static double levant_qc(const ft_law *L, const double *z) {
    const int r = L->r;
    const double *beta = L->par + 1, *e = L->par + r;
    double phi = z[0], N = fabs(phi), Psi = np_sign(phi);
    for (int i = 1; i < r; i++) {
        const double term = beta[i - 1] * scalar_pow(N, e[i - 1]);
        phi = z[i] + term * Psi;
        N = fabs(z[i]) + term;
        Psi = N > 0.0 ? phi / N : 0.0;
    }
    return -L->par[0] * Psi;
}

/* Linear feedback (linear.py LinearLaw.evaluate). par: K (r,), P (r, r) row-major. */
static void linear(const ft_law *L, const double *z, ft_out *o) {
    const int r = L->r;
    const double *K = L->par, *P = L->par + r;
    double Kz = 0.0, V = 0.0, Pz_last = 0.0;
    for (int i = 0; i < r; i++) Kz += z[i] * K[i];
    for (int j = 0; j < r; j++) {
        double Pz = 0.0; /* (z @ P)_j */
        for (int i = 0; i < r; i++) Pz += z[i] * P[i * r + j];
        V += z[j] * Pz;
        if (j == r - 1) Pz_last = Pz;
    }
    o->u = o->u0 = -Kz;
    o->V1 = V;
    o->dV1_dzr = 2.0 * Pz_last;
    o->gamma_hat = 1.0;
    o->phi_hat = 0.0 * 1.0;
}

/* The sliding variable s = z_r + sum c_i z_i and its known drift a = sum c_i z_{i+1}
 * (sliding_surface.py _SurfaceLaw.sliding_variable), c = (c_1..c_{r-1}). */
static inline void surface(const double *c, int r, const double *z, double *s, double *a) {
    if (r == 1) {
        *s = z[0];
        *a = 0.0;
        return;
    }
    double cz = 0.0, cdz = 0.0;
    for (int i = 0; i < r - 1; i++) {
        cz += z[i] * c[i];
        cdz += z[i + 1] * c[i];
    }
    *s = z[r - 1] + cz;
    *a = cdz;
}

/* One implicit super-twisting period (implicit.py super_twisting_step): w and v_{k+1}. */
static void super_twisting_step(double s, double v, double k1, double k2, double h, double *w, double *v_next) {
    const double m = s + h * v;
    const double excess = fabs(m) - h * h * k2;
    const double y = 0.5 * (-h * k1 + sqrt(h * h * k1 * k1 + 4.0 * np_maximum(excess, 0.0)));
    const int inside = excess <= 0.0;
    const double s_next = inside ? 0.0 : np_sign(m) * y * y;
    *v_next = inside ? -s / h : v - h * k2 * np_sign(m);
    *w = (s_next - s) / h;
}

/* Super-twisting (sliding_surface.py SuperTwisting). par: k1, k2, c_1..c_{r-1}. State (v,). */
static void super_twisting(const ft_law *L, const double *z, const double *x, ft_out *o, double *v_next) {
    const double k1 = L->par[0], k2 = L->par[1], v = x[0];
    double s, a, u;
    surface(L->par + 2, L->r, z, &s, &a);
    if (L->implicit) {
        double w;
        super_twisting_step(s, v, k1, k2, L->period, &w, v_next);
        u = -a + w;
    } else {
        u = -a - k1 * scalar_sig(s, 0.5) + v;
        *v_next = NAN; /* not known without h: ft_law_advance computes it */
    }
    only_u(o, u, 1.0, -v + 0.0 * u);
}

/* Plestan et al.'s adaptive sliding mode (sliding_surface.py PlestanAdaptive).
 * par: Kbar, mu, eps, c_1..c_{r-1}. State (K,). */
static void plestan(const ft_law *L, const double *z, const double *x, ft_out *o) {
    const double K = x[0];
    double s, a, w;
    surface(L->par + 3, L->r, z, &s, &a);
    if (L->implicit) {
        const double h = L->period;
        w = -np_clip((s + h * 0.0) / (h * 1.0), -K, K);
    } else w = -K * np_sign(s);
    const double u = -a + w;
    only_u(o, u, 1.0, K + 0.0 * u);
}

/* Fixed-time surface (fixed_time.py FixedTime.evaluate). par: ft_a, ft_b, switching. */
static double fixed_time(const ft_law *L, const double *z) {
    const double fa = L->par[0], fb = L->par[1], z2 = z[1];
    const double R = sqrt(fa * fa + 4.0 * fb * fabs(z2));
    const double X = 2.0 * fabs(z2) / (fa + R);
    const double n = (2.0 * fa / 3.0) * np_sign(z2) * sqrt(fabs(z2) * (fa + R) / 2.0)
                     + (4.0 * fb / 3.0) * z2 * sqrt(X);
    return -n - L->par[2] * np_sign(z[0] + np_sign(z2) * scalar_pow(X, 1.5));
}

/* Integral sliding mode around the minimum-energy control (integral_hosm.py IntegralHOSM).
 * par: t_final, switching, t_hold, c_1..c_r. State (tau, J). Returns u_nom. */
static double integral_hosm_nominal(const ft_law *L, const double *z, double tau) {
    const int r = L->r;
    const double T = np_maximum(L->par[0] - tau, L->par[2]);
    double acc = 0.0;
    for (int i = 0; i < r; i++) acc += L->par[3 + i] * z[i] / pow(T, (double)(r - i));
    return -acc;
}

void ft_law_eval(const ft_law *L, const double *z, const double *state, ft_out *o) {
    const int r = L->r;
    double s, a, unused;
    switch (L->law) {
    case FT_NOMINAL: case FT_ROBUST: case FT_ADAPTIVE:
        paper_eval(L, z, state ? state[0] : 0.0, o);
        return;
    case FT_LEVANT_NESTED:
        only_u(o, levant_nested(L, z), NAN, NAN);
        return;
    case FT_LEVANT_QC:
        only_u(o, levant_qc(L, z), NAN, NAN);
        return;
    case FT_LINEAR:
        linear(L, z, o);
        return;
    case FT_SUPER_TWISTING:
        super_twisting(L, z, state, o, &unused);
        return;
    case FT_PLESTAN:
        plestan(L, z, state, o);
        return;
    case FT_TWISTING: /* twisting.py: u = -r1 sign(z_1) - r2 sign(z_2); par: r1, r2 */
        only_u(o, -L->par[0] * np_sign(z[0]) - L->par[1] * np_sign(z[1]), NAN, NAN);
        return;
    case FT_TERMINAL: { /* terminal.py; par: beta, ratio, switching */
        const double beta = L->par[0], ratio = L->par[1];
        const double sv = z[0] + scalar_sig(z[1], ratio) / beta;
        only_u(o, -beta / ratio * scalar_sig(z[1], 2.0 - ratio) - L->par[2] * np_sign(sv), NAN, NAN);
        return;
    }
    case FT_FIXED_TIME:
        only_u(o, fixed_time(L, z), NAN, NAN);
        return;
    case FT_INTEGRAL_HOSM: {
        const double tau = state[0], J = state[1];
        const double u_nom = integral_hosm_nominal(L, z, tau);
        const double sv = tau > 0.0 ? z[r - 1] - J : 0.0;
        const double u = u_nom - L->par[1] * np_sign(sv);
        only_u(o, u, NAN, NAN);
        o->u0 = u_nom + 0.0 * u;
        return;
    }
    case FT_ADAPTIVE_ST: { /* adaptive_super_twisting.py; par: omega1, gamma1, mu_band, alpha_min,
                            * epsilon, eta_floor, c_1..c_{r-1}; state (v, alpha) */
        surface(L->par + 6, r, z, &s, &a);
        const double u = -a - state[1] * scalar_sig(s, 0.5) + state[0];
        only_u(o, u, 1.0, -state[0] + 0.0 * u);
        return;
    }
    case FT_HUANG: { /* huang_adaptive.py; par: Kbar, c_1..c_{r-1}; state (K,) */
        surface(L->par + 1, r, z, &s, &a);
        const double u = -a - state[0] * np_sign(s);
        only_u(o, u, 1.0, state[0] + 0.0 * u);
        return;
    }
    default: /* not a law of this kernel (Python never packs one) */
        only_u(o, NAN, NAN, NAN);
    }
}

void ft_law_advance(const ft_law *L, const double *z, double *state, const ft_out *o, double h) {
    const int r = L->r;
    double s, a;
    switch (L->law) {
    case FT_ADAPTIVE:
        state[0] = ft_advance_phi(L, o->V1, state[0], h);
        return;
    case FT_SUPER_TWISTING: {
        if (L->implicit) {
            ft_out again;
            double v_next;
            super_twisting(L, z, state, &again, &v_next);
            state[0] = v_next;
        } else {
            surface(L->par + 2, r, z, &s, &a);
            state[0] = state[0] - h * L->par[1] * np_sign(s);
        }
        return;
    }
    case FT_PLESTAN: { /* K + h K', K' = Kbar |s| sign(|s| - eps) where K > mu, mu elsewhere */
        surface(L->par + 3, r, z, &s, &a);
        const double K = state[0], Kbar = L->par[0], mu = L->par[1], eps = L->par[2];
        state[0] = K + h * (K > mu ? Kbar * fabs(s) * np_sign(fabs(s) - eps) : mu);
        return;
    }
    case FT_INTEGRAL_HOSM: { /* (tau, J) -> (tau + h, J + h u_nom), J = z_r at tau = 0 */
        const double tau = state[0], J = tau > 0.0 ? state[1] : z[r - 1];
        state[0] = tau + h;
        state[1] = J + h * o->u0;
        return;
    }
    case FT_ADAPTIVE_ST: { /* alpha moves by h alpha' (clipped at 0), v by the trapezoid of alpha */
        const double omega1 = L->par[0], gamma1 = L->par[1], mu_band = L->par[2], alpha_min = L->par[3];
        const double epsilon = L->par[4], eta_floor = L->par[5];
        surface(L->par + 6, r, z, &s, &a);
        const double v = state[0], alpha = state[1];
        const double grow = omega1 * sqrt(gamma1 / 2.0) * np_sign(fabs(s) - mu_band);
        const double alpha_next = np_maximum(alpha + h * (alpha > alpha_min ? grow : eta_floor), 0.0);
        state[0] = v - 2.0 * epsilon * np_sign(s) * 0.5 * h * (alpha + alpha_next);
        state[1] = alpha_next;
        return;
    }
    case FT_HUANG: /* K + h Kbar |s| */
        surface(L->par + 1, r, z, &s, &a);
        state[0] = state[0] + h * (L->par[0] * fabs(s));
        return;
    default: /* no state, or a state that does not move (Law.advance: x + h 0) */
        for (int i = 0; i < L->nstate; i++) state[i] = state[i] + h * 0.0;
    }
}

/* ---- batched entry points (ctypes, for the tests) ------------------------------------------------ */

/* The paper's law output for n states: z (n, r) row-major, phi_hat (n,); outputs (n,) each. */
void ft_law_output(const ft_law *L, int64_t n, const double *z, const double *phi_hat, double *u,
                   double *u0, double *V1, double *dV, double *gamma_hat, double *phi_hat_out) {
    ft_out o;
    for (int64_t k = 0; k < n; k++) {
        paper_eval(L, z + k * L->r, phi_hat[k], &o);
        u[k] = o.u; u0[k] = o.u0; V1[k] = o.V1; dV[k] = o.dV1_dzr;
        gamma_hat[k] = o.gamma_hat; phi_hat_out[k] = o.phi_hat;
    }
}

/* advance_phi_hat for n states: V1, phi_hat, out (n,). */
void ft_advance_phi_hat(const ft_law *L, int64_t n, const double *V1, const double *phi_hat, double h,
                        double *out) {
    for (int64_t k = 0; k < n; k++) out[k] = ft_advance_phi(L, V1[k], phi_hat[k], h);
}

/* One sample of any law for n (z, state) pairs, as the run loop takes it: z (n, r), state (n, nstate)
 * advanced in place over a period h; out[f] (n,) for the six LawOutput fields in their order. */
void ft_law_sample(const ft_law *L, int64_t n, const double *z, double *state, double h, double *const out[6]) {
    ft_out o;
    for (int64_t k = 0; k < n; k++) {
        double *x = L->nstate ? state + k * L->nstate : NULL;
        ft_law_eval(L, z + k * L->r, x, &o);
        out[0][k] = o.u; out[1][k] = o.u0; out[2][k] = o.V1; out[3][k] = o.dV1_dzr;
        out[4][k] = o.gamma_hat; out[5][k] = o.phi_hat;
        if (x) ft_law_advance(L, z + k * L->r, x, &o, h);
    }
}
