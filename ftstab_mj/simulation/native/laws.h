/* The control laws of the native kernel (laws.c): every registered law's C twin, and the helpers
 * that round as NumPy does. Shared by kernel.c (the ideal chain, the run callback) and laws.c.
 *
 * A law is one ft_law record (mirrored by the ctypes Structure FtLaw in __init__.py: keep them in
 * sync) and two calls: ft_law_eval (the LawOutput at z with the law's state) and ft_law_advance (the
 * state one control period later, z held). Every formula mirrors the NumPy code of
 * ftstab_mj/control/laws/ operation by operation (same order of floating-point operations); the law's
 * numbers (exponents included) are computed once in Python, so both paths use the same doubles.
 */
#ifndef FT_LAWS_H
#define FT_LAWS_H

#include <math.h>
#include <stdint.h>

#define FT_RMAX 8
#define FT_MAXSTATE 4                   /* numbers of state one law may keep */
#define FT_NPAR (FT_RMAX + FT_RMAX * FT_RMAX) /* par: the largest layout is linear's K (r) and P (r, r) */

/* The law numbers (Law.native_code in Python). */
enum {
    FT_NOMINAL = 0, FT_ROBUST = 1, FT_ADAPTIVE = 2,   /* the paper's, on Hong's controller */
    FT_LEVANT_NESTED = 3, FT_LEVANT_QC = 4, FT_LINEAR = 5, FT_SUPER_TWISTING = 6, FT_PLESTAN = 7,
    FT_TWISTING = 8, FT_TERMINAL = 9, FT_FIXED_TIME = 10, FT_INTEGRAL_HOSM = 11, FT_ADAPTIVE_ST = 12,
    FT_HUANG = 13,
    FT_NLAWS
};

/* One law. The paper's laws use Hong's fields (r, form, gains, beta, expo) and their own named
 * parameters; every other law reads its numbers from par, in the order its Python class's
 * native_params() lists them (the layout is written next to each law in laws.c). */
typedef struct {
    int32_t r;          /* chain length, 1..FT_RMAX */
    int32_t simplified; /* Hong's form: 0 full, 1 simplified (Proposition 1) */
    int32_t law;        /* FT_NOMINAL .. */
    int32_t substeps;   /* RK4 sub-steps of advance_phi_hat in the transition band */
    double gains[FT_RMAX];
    double beta[FT_RMAX];
    double expo[FT_RMAX];
    double phibar, gamma_m;                  /* robust */
    double kappa, delta, rate, eta, eps;     /* adaptive */
    int32_t nstate;     /* numbers of state (Law.state_size), <= FT_MAXSTATE */
    int32_t implicit;   /* 1: the implicit discretization of the sign term (control/implicit.py) */
    double period;      /* the control period the implicit discretization predicts over (s) */
    double par[FT_NPAR];
} ft_law;

/* One evaluation of a law: the fields of LawOutput. */
typedef struct {
    double u, u0, V1, dV1_dzr, gamma_hat, phi_hat;
} ft_out;

/* np.sign: -1, 0, +1, NaN for NaN. */
static inline double np_sign(double a) {
    return a > 0.0 ? 1.0 : (a < 0.0 ? -1.0 : (a == 0.0 ? 0.0 : a));
}

/* |a|^p, without pow where NumPy does without it too (its power has fast paths for these
 * exponents): 0^p = 0 (p > 0), x^1 = x (the full form's first exponent), x^0.5 = sqrt(x) and
 * x^2 = x x (the adaptive law with eta = 0.5, the default, in advance_phi: 4x cheaper). */
static inline double abs_pow(double a, double p) {
    double m = fabs(a);
    if (m == 0.0 || p == 1.0) return m;
    if (p == 0.5) return sqrt(m);
    if (p == 2.0) return m * m;
    return pow(m, p);
}

/* np.maximum and np.minimum (NaN propagates, unlike fmax and fmin). */
static inline double np_maximum(double a, double b) {
    return (a != a || a >= b) ? a : b;
}
static inline double np_minimum(double a, double b) {
    return (a != a || a <= b) ? a : b;
}

/* np.clip(x, lo, hi) = minimum(maximum(x, lo), hi). */
static inline double np_clip(double x, double lo, double hi) { return np_minimum(np_maximum(x, lo), hi); }

/* The law's output at z (r,) with its state (nstate,; NULL when it has none). */
void ft_law_eval(const ft_law *L, const double *z, const double *state, ft_out *o);

/* The law's state one period h later with z held, in place (o: ft_law_eval's output at z, state). */
void ft_law_advance(const ft_law *L, const double *z, double *state, const ft_out *o, double h);

/* phi_hat after one period h with V1 held (the adaptive law; any other law: phi_hat + 0). */
double ft_advance_phi(const ft_law *L, double V1, double phi_hat, double h);

#endif
