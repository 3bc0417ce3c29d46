/* Native kernel: the C twin of the NumPy reference in ftstab_mj/control/ and ftstab_mj/simulation/
 * (the ideal chain, the loop stages, the run loop's control callback); the laws are in laws.c.
 *
 * Loaded with ctypes (ftstab_mj/simulation/native/__init__.py); the Python module init at the bottom only
 * exists so that setuptools can build this file as an ordinary (optional) extension.
 *
 * Every formula mirrors the NumPy code operation by operation (same order of floating-point
 * operations), so the two agree to rounding: NumPy's SIMD pow and libm's pow may differ by one ulp,
 * nothing else differs. The law parameters (exponents included) are computed once in Python and
 * copied into ft_law, so both paths use bit-identical exponents.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdatomic.h>
#if defined(__unix__) || defined(__APPLE__)
#define FT_THREADS 1
#include <pthread.h>
#endif

#include "laws.h"

#define FT_MAXLOOPS 8 /* loops of one native run */

/* An input of the ideal chain (phi or gamma): either a table over the sub-step instants
 * (values[step * substeps + s], the same for every trajectory) or a state-dependent signal
 * (values NULL, disturbances.py "worst_case") given by its three values for dV1/dz_r > 0, < 0, = 0,
 * which Python evaluates with the Signal itself (the sign convention lives there only). */
typedef struct {
    const double *values;
    double if_pos, if_neg, if_zero;
} ft_input;

static inline double input_at(const ft_input *in, int64_t idx, double dV) {
    if (in->values) return in->values[idx];
    return dV > 0.0 ? in->if_pos : (dV < 0.0 ? in->if_neg : (dV == 0.0 ? in->if_zero : dV));
}

/* The ideal chain (ideal_chain.py simulate_chain) for trajectories j0..j1-1 of n over nsteps periods.
 * z: (n, r) initial states, overwritten by the final states; phi_hat: (n,) likewise.
 * Phi (r, r), G (r,): transition over one sub-step. Records, one row per period (nsteps, n, ...):
 * zs (nsteps, n, r) and rec[f] (nsteps, n) for f in u, u0, V1, dV1_dzr, phi_hat, gamma_hat, phi, gamma.
 * Time-major loops, so that the records are written sequentially. */
typedef struct {
    const ft_law *L;
    int64_t n, j0, j1, nsteps;
    double *z, *phi_hat;
    int32_t substeps;
    double period;
    const double *Phi, *G;
    const ft_input *phi_in, *gam_in;
    double *zs;
    double *const *rec;
} chain_job;

static void *chain_run(void *arg) {
    const chain_job *J = (const chain_job *)arg;
    const ft_law *L = J->L;
    const int r = L->r;
    const int64_t n = J->n;
    ft_out o;
    for (int64_t k = 0; k < J->nsteps; k++) {
        for (int64_t j = J->j0; j < J->j1; j++) {
            double *x = J->z + j * r, y[FT_RMAX];
            ft_law_eval(L, x, J->phi_hat + j, &o);
            const int64_t row = k * n + j;
            for (int i = 0; i < r; i++) J->zs[row * r + i] = x[i];
            J->rec[0][row] = o.u; J->rec[1][row] = o.u0; J->rec[2][row] = o.V1; J->rec[3][row] = o.dV1_dzr;
            J->rec[4][row] = o.phi_hat; J->rec[5][row] = o.gamma_hat;
            for (int s = 0; s < J->substeps; s++) {
                const int64_t idx = k * J->substeps + s;
                const double wp = input_at(J->phi_in, idx, o.dV1_dzr), wg = input_at(J->gam_in, idx, o.dV1_dzr);
                if (s == 0) { J->rec[6][row] = wp; J->rec[7][row] = wg; }
                const double w = wp + wg * o.u;
                for (int i = 0; i < r; i++) {
                    double acc = 0.0;
                    for (int c = i; c < r; c++) acc += x[c] * J->Phi[i * r + c];
                    y[i] = acc + w * J->G[i];
                }
                for (int i = 0; i < r; i++) x[i] = y[i];
            }
            J->phi_hat[j] = ft_advance_phi(L, o.V1, J->phi_hat[j], J->period);
        }
    }
    return NULL;
}

#define FT_MAXTHREADS 64

/* Trajectories are independent: with threads > 1 (POSIX) they are split into that many slices
 * run in parallel; each thread writes its own columns of the records, so the result does not
 * depend on the number of threads. */
void ft_simulate_chain(const ft_law *L, int64_t n, double *z, double *phi_hat, int64_t nsteps,
                       int32_t substeps, double period, const double *Phi, const double *G,
                       const ft_input *phi_in, const ft_input *gam_in, double *zs, double *const rec[8],
                       int32_t threads) {
    chain_job jobs[FT_MAXTHREADS];
    if (threads < 1) threads = 1;
    if (threads > FT_MAXTHREADS) threads = FT_MAXTHREADS;
    if (threads > n) threads = (int32_t)(n > 0 ? n : 1);
    for (int t = 0; t < threads; t++) {
        chain_job J = {L, n, n * t / threads, n * (t + 1) / threads, nsteps, z, phi_hat, substeps, period,
                       Phi, G, phi_in, gam_in, zs, rec};
        jobs[t] = J;
    }
#ifdef FT_THREADS
    pthread_t tid[FT_MAXTHREADS];
    int started[FT_MAXTHREADS] = {0};
    for (int t = 1; t < threads; t++) started[t] = pthread_create(&tid[t], NULL, chain_run, &jobs[t]) == 0;
    chain_run(&jobs[0]);
    for (int t = 1; t < threads; t++) {
        if (started[t]) pthread_join(tid[t], NULL);
        else chain_run(&jobs[t]); /* could not start a thread: do its share here */
    }
#else
    for (int t = 0; t < threads; t++) chain_run(&jobs[t]);
#endif
}

/* ---- the loop stages (ftstab_mj/simulation/stages/): sensor, Levant's differentiator, actuator ----------
 *
 * The C twin of loop_stages/pipeline.py LoopStages.measure and .actuate, operation by operation.
 * The sensor noise is drawn in Python (a pure function of seed, loop and sample) and handed over
 * as a table per batch; the differentiator's gains and exponents are computed in Python too. */

#define FT_OBSMAX 6 /* differentiator states: order + 1 + filter order <= 6 (levant.py MAX_TOTAL_ORDER + 1) */

typedef struct {
    int32_t r, m, delay, observer, order, nf, N, pad;
    double noise_amp[FT_RMAX], quantum[FT_RMAX];
    double z_gain[FT_OBSMAX], z_pow[FT_OBSMAX], w_gain[FT_OBSMAX], w_pow[FT_OBSMAX];
    double u_max, rate_max, tau, dead_zone;
    double decay, mean, h, h_tau, c_a, c_b; /* exp(-h/tau), tau/h (1 - decay), h, h/tau, tau (1 - decay), c_a - h decay */
    int32_t lag_order, pad2;
    double period;
    int32_t noisy, quantized;
    const double *noise;   /* (samples of the batch, m) unit noise, row = sample of the batch */
} ft_stage;

static inline double sig_pow(double a, double p) { return np_sign(a) * pow(fabs(a), p); }

/* np.power(x, j) for a small whole j (NumPy's fast paths for 1 and 2, libm's pow otherwise). */
static inline double int_pow(double x, int j) { return j == 1 ? x : (j == 2 ? x * x : pow(x, (double)j)); }

/* One step of the sampled differentiator (levant.py LevantDifferentiator.step), in place. */
static void levant_step(const ft_stage *S, double *st, double f) {
    const int n = S->order, nf = S->nf;
    const double tau = S->period;
    double z[FT_OBSMAX] = {0}, out[FT_OBSMAX] = {0};
    for (int i = 0; i < n + 1 + nf; i++) z[i] = st[i];
    const double e = nf ? z[n + 1] : z[0] - f;
    for (int i = 0; i <= n; i++) out[i] = z[i] - tau * S->z_gain[i] * sig_pow(e, S->z_pow[i]);
    double fact = 1.0;
    for (int j = 1; j <= n; j++) {
        fact *= j;
        const double c = int_pow(tau, j) / fact;
        for (int i = 0; i <= n - j; i++) out[i] += c * z[i + j];
    }
    for (int j = 0; j < nf; j++) {
        const double drive = j + 1 < nf ? z[n + 2 + j] : z[0] - f;
        out[n + 1 + j] = z[n + 1 + j] + tau * (drive - S->w_gain[j] * sig_pow(e, S->w_pow[j]));
    }
    for (int i = 0; i < n + 1 + nf; i++) st[i] = out[i];
}

/* LoopStages.measure: sample k (row of the batch), true z (r,) -> z_meas (m,), z_hat (r,); state updated. */
static void stage_measure(const ft_stage *S, int64_t k, int64_t row, const double *z, double *state,
                          double *zm, double *zh) {
    const int m = S->m, d = S->delay;
    double y[FT_RMAX];
    for (int c = 0; c < m; c++) {
        double v = z[c];
        if (S->noisy) v += S->noise_amp[c] * S->noise[row * m + c];
        if (S->quantized && S->quantum[c] > 0.0) v = S->quantum[c] * nearbyint(v / S->quantum[c]);
        y[c] = v;
    }
    double *line = state, *obs = state + d * m;
    if (k == 0)
        for (int q = 0; q < d; q++)
            for (int c = 0; c < m; c++) line[q * m + c] = y[c];
    if (d) {
        for (int c = 0; c < m; c++) zm[c] = line[c];
        for (int q = 0; q + 1 < d; q++)
            for (int c = 0; c < m; c++) line[q * m + c] = line[(q + 1) * m + c];
        for (int c = 0; c < m; c++) line[(d - 1) * m + c] = y[c];
    } else {
        for (int c = 0; c < m; c++) zm[c] = y[c];
    }
    if (!S->observer) {
        for (int c = 0; c < m; c++) zh[c] = zm[c];
        return;
    }
    if (k == 0) {
        obs[0] = zm[0];
        for (int i = 1; i < S->order + 1 + S->nf; i++) obs[i] = 0.0;
    }
    for (int i = 0; i < S->r; i++) zh[i] = obs[i];
    levant_step(S, obs, zm[0]);
}

/* LoopStages.actuate: the law's u at sample k -> the plant's input at each of the N steps; state updated.
 * Returns u_applied (the input at the first step). */
static double stage_actuate(const ft_stage *S, int64_t k, double u, double *state, double *steps) {
    double *act = state + S->delay * S->m + (S->observer ? S->order + 1 + S->nf : 0);
    if (k == 0) act[0] = act[1] = act[2] = 0.0;
    if (S->dead_zone != 0.0) u = copysign(fmax(fabs(u) - S->dead_zone, 0.0), u);
    if (S->u_max != INFINITY) u = fmin(fmax(u, -S->u_max), S->u_max);
    if (S->rate_max != INFINITY) {
        const double step = S->rate_max * S->period, prev = act[0];
        u = fmin(fmax(u, prev - step), prev + step);
    }
    if (S->tau == 0.0) {
        for (int s = 0; s < S->N; s++) steps[s] = u;
        act[0] = act[1] = act[2] = u;
        return steps[0];
    }
    const double x1 = act[1], x2 = act[2];
    double e1 = 0.0, e2 = 0.0;
    for (int s = 0; s <= S->N; s++) {
        const double pw = pow(S->decay, (double)s);
        e1 = (x1 - u) * pw;
        if (S->lag_order == 2) e2 = ((x2 - u) + (x1 - u) * ((double)s * S->h_tau)) * pw;
        if (s == S->N) break;
        steps[s] = S->lag_order == 2 ? u + (e2 * S->c_a + e1 * S->c_b) / S->h : u + e1 * S->mean;
    }
    act[0] = u;
    act[1] = u + e1;
    act[2] = S->lag_order == 2 ? u + e2 : u + e1;
    return steps[0];
}

/* Test entry points: n consecutive samples k0.. of one loop (z (n, r) true states, u (n,) law outputs). */
void ft_stage_measure(const ft_stage *S, int64_t k0, int64_t n, const double *z, double *state, double *zm,
                      double *zh) {
    for (int64_t j = 0; j < n; j++)
        stage_measure(S, k0 + j, j, z + j * S->r, state, zm + j * S->m, zh + j * S->r);
}

void ft_stage_actuate(const ft_stage *S, int64_t k0, int64_t n, const double *u, double *state, double *steps) {
    for (int64_t j = 0; j < n; j++) stage_actuate(S, k0 + j, u[j], state, steps + j * S->N);
}

int64_t ft_stage_size(void) { return (int64_t)sizeof(ft_stage); }

/* ---- chain plants (ftstab_mj/plants/chain.py): the C twin of ChainPlant.sense and true_chain ------
 *
 * A chain plant's loops sit on any dofs and actuators of a model (dof[i], act[i]); z is read as
 * weighted sums of sensor readings (z[i][j] = sum_k w sensordata[adr], adr -1 unused), and the true
 * phi and gamma come from MuJoCo's own stage functions (called through pointers into the libmujoco
 * the Python bindings loaded): qacc_smooth after mj_fwdActuation + mj_fwdAcceleration, (M^-1)_ii
 * from mj_solveM, and for r = 3 the central difference of qacc_smooth along the state's derivative
 * on a private MjData. The operations and their order are those of chain.py, so both paths agree
 * to rounding. The layout is mirrored by FtChain in native/run.py: keep them in sync. */
typedef void (*ft_mjfn)(const void *m, void *d);
typedef void (*ft_solvefn)(const void *m, void *d, double *x, const double *y, int n);

typedef struct {
    int32_t K, nv, nq, na, nu, integrating;
    const int32_t *adr;          /* (n, r, K) */
    const double *w;             /* (n, r, K) */
    const int32_t *dof, *act;    /* (n,) */
    const double *b, *dist_scale; /* (n,) gain x gear, generalized force per unit of injected phi */
    ft_mjfn fwd_position, fwd_velocity, fwd_actuation, fwd_acceleration;
    ft_solvefn solve_m;
    /* the run's MjData */
    const double *qpos, *qvel, *act_state, *act_dot, *qacc_smooth, *qfrc_applied, *ctrl;
    /* the private MjData of the central difference */
    void *s;
    double *s_qpos, *s_qvel, *s_act, *s_qfrc_applied, *s_ctrl;
    const double *s_qacc_smooth;
    double eps;
    double *work;                /* 2 n nv + 3 nv + 2 n doubles */
    /* the actuators' clamps (NULL: none clamps): ctrl = gain u to [ctrl_lo, ctrl_hi], then the force
     * gainprm ctrl to [force_lo, force_hi] (plants/chain.py ChainPlant.applied) */
    const int32_t *clamp_on;
    const double *ctrl_lo, *ctrl_hi, *force_lo, *force_hi, *gainprm;
    /* full != 0: the model has contacts, limits or equality constraints; phi and gamma come from the
     * constraint solver on the private MjData (plants/chain.py ChainPlant._full_chain) */
    int32_t full;
    ft_mjfn fwd_constraint;
    const double *qacc_warmstart;
    double *s_qacc_warmstart, *warm;
    const double *s_qacc;
    double tau_step;
} ft_chain;

/* The control loop i's actuator applies for the law's u: ChainPlant.applied, operation for operation. */
static inline double chain_applied(const ft_chain *C, int i, double u, double gain) {
    const double c = gain * u;
    const double cc = fmin(fmax(c, C->ctrl_lo[i]), C->ctrl_hi[i]);
    const double f = C->gainprm[i] * cc;
    const double fc = fmin(fmax(f, C->force_lo[i]), C->force_hi[i]);
    if (fc != f) return fc / (C->gainprm[i] * gain);
    return cc != c ? cc / gain : u;
}

static inline double chain_read(const ft_chain *C, const double *sensordata, int i, int j, int r) {
    double acc = 0.0;
    const int base = (i * r + j) * C->K;
    for (int k = 0; k < C->K; k++)
        if (C->adr[base + k] >= 0) acc = acc + C->w[base + k] * sensordata[C->adr[base + k]];
    return acc;
}

/* q'' of the loops' dofs after the constraint solver on the private MjData, from d's warmstart. */
static void chain_full_acc(const ft_chain *C, const void *m, int n, double *out) {
    for (int c = 0; c < C->nv; c++) C->s_qacc_warmstart[c] = C->warm[c];
    C->fwd_actuation(m, C->s);
    C->fwd_acceleration(m, C->s);
    C->fwd_constraint(m, C->s);
    for (int i = 0; i < n; i++) out[i] = C->s_qacc[C->dof[i]];
}

/* ChainPlant._full_chain, operation for operation. */
static void chain_full(const ft_chain *C, const void *m, int n, const double *u, const double *gain,
                       double *phi, double *gamma) {
    for (int c = 0; c < C->nq; c++) C->s_qpos[c] = C->qpos[c];
    for (int c = 0; c < C->nv; c++) {
        C->s_qvel[c] = C->qvel[c];
        C->s_qfrc_applied[c] = C->qfrc_applied[c];
        C->warm[c] = C->qacc_warmstart[c];
    }
    for (int c = 0; c < C->na; c++) C->s_act[c] = C->act_state[c];
    for (int c = 0; c < C->nu; c++) C->s_ctrl[c] = C->ctrl[c];
    C->fwd_position(m, C->s);
    C->fwd_velocity(m, C->s);
    double qacc[FT_MAXLOOPS], acc[FT_MAXLOOPS];
    chain_full_acc(C, m, n, qacc);
    for (int i = 0; i < n; i++) {
        const int dof = C->dof[i];
        const double base = C->s_qfrc_applied[dof];
        C->s_qfrc_applied[dof] = base + C->tau_step;
        chain_full_acc(C, m, n, acc);
        const double plus = acc[i];
        C->s_qfrc_applied[dof] = base - C->tau_step;
        chain_full_acc(C, m, n, acc);
        const double minus = acc[i];
        C->s_qfrc_applied[dof] = base;
        gamma[i] = gain[i] * C->b[i] * (plus - minus) / (2.0 * C->tau_step);
    }
    for (int i = 0; i < n; i++) phi[i] = qacc[i] - gamma[i] * u[i];
}

/* phi, gamma (n,) of the sample, after its ctrl (and r = 2 disturbance) were written into d. */
static void chain_truth(const ft_chain *C, const void *m, void *d, int n, const double *u, const double *gain,
                        const double *inj, double *phi, double *gamma) {
    if (C->full) {
        chain_full(C, m, n, u, gain, phi, gamma);
        return;
    }
    const int nv = C->nv;
    double *e = C->work, *x = e + n * nv, *acc = x + n * nv, *rate = acc + 2 * n, *qacc = rate + nv;
    C->fwd_actuation(m, d);
    C->fwd_acceleration(m, d);
    for (int k = 0; k < n * nv; k++) e[k] = 0.0;
    for (int i = 0; i < n; i++) e[i * nv + C->dof[i]] = 1.0;
    C->solve_m(m, d, x, e, n);
    for (int i = 0; i < n; i++) gamma[i] = gain[i] * (C->b[i] * x[i * nv + C->dof[i]]);
    if (!C->integrating) {
        for (int i = 0; i < n; i++) phi[i] = C->qacc_smooth[C->dof[i]] - gamma[i] * u[i];
        return;
    }
    for (int c = 0; c < nv; c++) { rate[c] = 0.0; qacc[c] = C->qacc_smooth[c]; }
    for (int i = 0; i < n; i++) rate[C->dof[i]] = C->dist_scale[i] * inj[i];
    for (int side = 0; side < 2; side++) {
        const double h = (side == 0 ? 1.0 : -1.0) * C->eps;
        for (int c = 0; c < C->nq; c++) C->s_qpos[c] = C->qpos[c] + h * C->qvel[c];
        for (int c = 0; c < nv; c++) {
            C->s_qvel[c] = C->qvel[c] + h * qacc[c];
            C->s_qfrc_applied[c] = C->qfrc_applied[c] + h * rate[c];
        }
        for (int c = 0; c < C->na; c++) C->s_act[c] = C->act_state[c] + h * C->act_dot[c];
        for (int c = 0; c < C->nu; c++) C->s_ctrl[c] = C->ctrl[c];
        C->fwd_position(m, C->s);
        C->fwd_velocity(m, C->s);
        C->fwd_actuation(m, C->s);
        C->fwd_acceleration(m, C->s);
        for (int i = 0; i < n; i++) acc[side * n + i] = C->s_qacc_smooth[C->dof[i]];
    }
    for (int i = 0; i < n; i++) phi[i] = (acc[i] - acc[n + i]) / (2.0 * C->eps) - gamma[i] * u[i];
}

/* ChainPlant.sense + true_chain for one state, for the tests (the run uses them inside the callback). */
void ft_chain_eval(const ft_chain *C, const void *m, void *d, int32_t n, int32_t r, const double *sensordata,
                   const double *u, const double *gain, const double *inj, double *z, double *phi, double *gamma) {
    for (int i = 0; i < n; i++)
        for (int j = 0; j < r; j++) z[i * r + j] = chain_read(C, sensordata, i, j, r);
    chain_truth(C, m, d, n, u, gain, inj, phi, gamma);
}

int64_t ft_chain_size(void) { return (int64_t)sizeof(ft_chain); }

/* ---- the control callback of the MuJoCo run loop (ftstab_mj/simulation/run_loop.py, native path) ----------------
 *
 * The C twin of Simulation._sample plus the per-step input writes of Simulation.advance, so that a
 * whole batch runs inside mj_step(m, d, nstep). It knows nothing of the mjData struct's layout: at
 * configure time Python finds the offsets of d->time and of the array pointers it uses (ft_layout), and
 * each call reads them from the d it is called with. It is called once per forward pass; the step it belongs to is (time - t0) / h rounded, so a
 * repeated call at the same time (a stray forward pass) does nothing and a jump of time (MuJoCo
 * resetting the data after a bad state) stops the batch. One forward pass per step: Euler and
 * implicitfast (RK4 runs the Python path). */

enum { FT_RUNNING = 0, FT_DIVERGED_Z = 1, FT_BAD_CONTROL = 2, FT_TIME_JUMP = 3 };

typedef struct {
    /* the MjData of the current call (bound by bind_data at each call) */
    const double *time;
    double *ctrl, *qfrc_applied, *userdata;
    const double *sensordata, *qvel, *xpos, *xquat;
    /* non-NULL: refresh the sensors before each sample with mj_forwardSkip(m, d, skip_stage, 0) */
    void (*mj_forward_skip)(const void *m, void *d, int skipstage, int skipsensor);
    int32_t skip_stage;
    /* the loops */
    int32_t n, N, integrating, nbody;
    const int32_t *sensor_adr;   /* (n, r) indices into sensordata: z[i][j] = sensordata[adr[i*r+j]] */
    const int32_t *body_ids;     /* (nbody,) */
    const double *refs;          /* (n,) set points, z_1 = q - ref */
    const ft_law *laws;          /* (n,) */
    const double *phi_damping, *phi_mass; /* (n,): recorded phi = inj - damping * qvel[i] / mass */
    const int32_t *phi_state;    /* (n,) 1 when phi is state dependent (then given by state_phi[i]) */
    const ft_input *state_phi;   /* (n,) */
    const double *force_factor;  /* (n,) */
    const int32_t *state_adr;    /* (n,) userdata index of loop i's law state (laws[i].nstate numbers), -1: none */
    double period, h, divergence_limit;
    /* the batch (arrays (nsteps, n) unless said) */
    double t0;                   /* time of its first step */
    int64_t nsteps;
    const double *t;             /* (nsteps / N,) sample times */
    double *inj, *force, *ctrl_steps;
    const double *gain;
    double *u_held;              /* (n,) */
    double *rec_t;               /* (samples,) */
    double *rec_z;               /* (n, samples, r) */
    double *rec[8];              /* (n, samples) each: u u0 V1 dV1_dzr phi_hat gamma_hat phi gamma */
    double *body_pos, *body_quat; /* (samples, nbody, 3|4) */
    int64_t samples;
    /* progress and outcome (read by Python) */
    int64_t last_step, row;      /* last step handled (-1 none), last sample recorded (-1 none) */
    int32_t status, bad_loop;
    double bad_value, bad_time;
    int32_t busy;
    /* the loop stages (loop_stages/pipeline.py LoopStages; stage_on NULL: no loop has any) */
    ft_stage *stages;            /* (n,) their noise tables are set per batch */
    const int32_t *stage_on;     /* (n,) 1 when loop i has stages */
    const int32_t *stage_adr;    /* (n,) userdata index of loop i's stage state */
    int64_t k0;                  /* index of the batch's first sample since t = 0 */
    double *u_steps;             /* (N,) scratch: the actuator's output at each step of the period */
    double *rec_zm[FT_MAXLOOPS], *rec_zh[FT_MAXLOOPS], *rec_ua[FT_MAXLOOPS]; /* (samples, m), (samples, r), (samples,) */
    const ft_chain *chain;       /* a chain plant's readout and truth (NULL: z from sensor_adr, phi from inj) */
    const double *ref_table;     /* (samples, n, r + 1) ref^(j)(t_k) of tracked references; NULL: set points refs */
} ft_run;

/* The ctrl and qfrc_applied index of loop i. */
static inline int ctrl_of(const ft_run *R, int i) { return R->chain ? R->chain->act[i] : i; }
static inline int dof_of(const ft_run *R, int i) { return R->chain ? R->chain->dof[i] : i; }

static void run_sample(ft_run *R, const void *m, void *d, int64_t s) {
    const int n = R->n, N = R->N;
    const int64_t row = R->row + 1, S = R->samples;
    const double t = R->t[row];
    if (R->mj_forward_skip) {
        /* The sensors of the acceleration stage are computed after this callback: run the stages
         * after velocity once more, with the control still held from the last step, as the Python
         * loop's mj_forward before the step does (position and velocity stages: this pass's, the
         * same state, so they need not be recomputed). */
        R->busy = 1;
        R->mj_forward_skip(m, d, R->skip_stage, 0);
        R->busy = 0;
    }
    double z[FT_RMAX * FT_MAXLOOPS], zmax = 0.0;
    int nan = 0;
    for (int i = 0; i < n; i++) {
        const int r = R->laws[i].r;
        for (int j = 0; j < r; j++) {
            double v = R->chain ? chain_read(R->chain, R->sensordata, i, j, r) : R->sensordata[R->sensor_adr[i * r + j]];
            if (R->ref_table) v -= R->ref_table[(row * n + i) * (r + 1) + j];
            else if (j == 0) v -= R->refs[i];
            z[i * FT_RMAX + j] = v;
            if (!(fabs(v) <= zmax)) { if (v != v) nan = 1; else zmax = fabs(v); }
        }
    }
    if (nan || !(zmax <= R->divergence_limit)) {
        R->status = FT_DIVERGED_Z;
        R->bad_value = nan ? NAN : zmax;
        R->bad_time = t;
        for (int i = 0; i < n; i++) R->ctrl[ctrl_of(R, i)] = 0.0;
        return;
    }
    /* what the laws see: z, or a staged loop's sensor reading through its observer */
    double zlaw[FT_RMAX * FT_MAXLOOPS];
    for (int i = 0; i < n; i++) {
        const int r = R->laws[i].r;
        if (R->stage_on && R->stage_on[i]) {
            const ft_stage *S = &R->stages[i];
            stage_measure(S, R->k0 + row, row, z + i * FT_RMAX, R->userdata + R->stage_adr[i],
                          R->rec_zm[i] + row * S->m, zlaw + i * FT_RMAX);
            for (int j = 0; j < r; j++) R->rec_zh[i][row * r + j] = zlaw[i * FT_RMAX + j];
        } else {
            for (int j = 0; j < r; j++) zlaw[i * FT_RMAX + j] = z[i * FT_RMAX + j];
        }
    }
    ft_out o;
    for (int i = 0; i < n; i++) {
        const ft_law *L = &R->laws[i];
        const int32_t adr = R->state_adr[i];
        double *state = adr >= 0 ? R->userdata + adr : NULL;
        const double *zi = z + i * FT_RMAX;
        ft_law_eval(L, zlaw + i * FT_RMAX, state, &o);
        if (R->phi_state[i]) { /* worst case: held over the period with this sample's dV1/dz_r */
            const double value = input_at(&R->state_phi[i], 0, o.dV1_dzr);
            for (int64_t k = s; k < s + N; k++) {
                R->inj[k * n + i] = value;
                R->force[k * n + i] = value * R->force_factor[i];
            }
        }
        if (!isfinite(o.u)) {
            R->status = FT_BAD_CONTROL;
            R->bad_loop = i;
            R->bad_value = o.u;
            R->bad_time = t;
            for (int q = 0; q < n; q++) R->ctrl[ctrl_of(R, q)] = 0.0;
            return;
        }
        R->u_held[i] = o.u;
        const int64_t at = i * S + row;
        for (int j = 0; j < L->r; j++) R->rec_z[at * L->r + j] = zi[j];
        R->rec[0][at] = o.u; R->rec[1][at] = o.u0; R->rec[2][at] = o.V1; R->rec[3][at] = o.dV1_dzr;
        R->rec[4][at] = o.phi_hat; R->rec[5][at] = o.gamma_hat; /* the law's phi_hat, as sim.py logs it */
        if (state) ft_law_advance(L, zlaw + i * FT_RMAX, state, &o, R->period);
    }
    R->rec_t[row] = t;
    for (int i = 0; i < n; i++) {
        if (R->stage_on && R->stage_on[i]) { /* the actuator's output at each step of the period */
            R->rec_ua[i][row] = stage_actuate(&R->stages[i], R->k0 + row, R->u_held[i],
                                              R->userdata + R->stage_adr[i], R->u_steps);
            for (int64_t k = s; k < s + N; k++) R->ctrl_steps[k * n + i] = R->gain[k * n + i] * R->u_steps[k - s];
        } else {
            for (int64_t k = s; k < s + N; k++) R->ctrl_steps[k * n + i] = R->gain[k * n + i] * R->u_held[i];
        }
    }
    for (int i = 0; i < n; i++) {
        R->ctrl[ctrl_of(R, i)] = R->ctrl_steps[s * n + i];
        if (!R->integrating) R->qfrc_applied[dof_of(R, i)] = R->force[s * n + i];
        if (R->chain) continue;
        const int64_t at = i * S + row;
        R->rec[6][at] = R->inj[s * n + i] - R->phi_damping[i] * R->qvel[i] / R->phi_mass[i];
        R->rec[7][at] = R->gain[s * n + i];
    }
    if (R->chain) {
        double phi[FT_MAXLOOPS], gamma[FT_MAXLOOPS], ua[FT_MAXLOOPS] = {0.0}; /* the actuator's output, as sim.py */
        for (int i = 0; i < n; i++) ua[i] = (R->stage_on && R->stage_on[i]) ? R->rec_ua[i][row] : R->u_held[i];
        if (R->chain->clamp_on)
            for (int i = 0; i < n; i++)
                if (R->chain->clamp_on[i]) {
                    ua[i] = chain_applied(R->chain, i, ua[i], R->gain[s * n + i]);
                    R->rec_ua[i][row] = ua[i];
                }
        chain_truth(R->chain, m, d, n, ua, R->gain + s * n, R->inj + s * n, phi, gamma);
        for (int i = 0; i < n; i++) {
            R->rec[6][i * S + row] = phi[i];
            R->rec[7][i * S + row] = gamma[i];
        }
    }
    if (R->ref_table) /* the error chain's phi: z_r' = q^(r) - ref^(r) */
        for (int i = 0; i < n; i++) {
            const int r = R->laws[i].r;
            R->rec[6][i * S + row] = R->rec[6][i * S + row] - R->ref_table[(row * n + i) * (r + 1) + r];
        }
    for (int b = 0; b < R->nbody; b++) {
        for (int c = 0; c < 3; c++) R->body_pos[(row * R->nbody + b) * 3 + c] = R->xpos[R->body_ids[b] * 3 + c];
        for (int c = 0; c < 4; c++) R->body_quat[(row * R->nbody + b) * 4 + c] = R->xquat[R->body_ids[b] * 4 + c];
    }
    R->row = row;
}

/* ---- the runs the callback serves: found from the MjData it is called with ------------------------
 *
 * MuJoCo's control callback is one global function pointer, so one callback serves every run of the
 * process; each call finds its run from its MjData d, registered under d's address while the run
 * steps (ft_run_activate .. ft_run_finish). The arrays of d are read through byte offsets inside
 * the mjData struct (ft_layout, found once by Python for the model), never through addresses of
 * one MjData, so a run works on whichever MjData it is called with, on any thread. */

/* Byte offsets inside mjData of the field time and of the pointer fields the callback uses. */
typedef struct {
    int64_t time, ctrl, qfrc_applied, userdata, sensordata, qvel, xpos, xquat;
} ft_layout;

#define FT_MAXACTIVE 256
typedef struct {
    _Atomic(const void *) d; /* the MjData of a single run (NULL: free slot) */
    ft_run *R;
    ft_layout lay;
} ft_slot;
static ft_slot ft_slots[FT_MAXACTIVE];
static atomic_int ft_high = 0;                /* slots in use are below this index */
static atomic_flag ft_slots_lock = ATOMIC_FLAG_INIT; /* writers only; readers are lock-free */

static void slots_lock(void) { while (atomic_flag_test_and_set_explicit(&ft_slots_lock, memory_order_acquire)) {} }
static void slots_unlock(void) { atomic_flag_clear_explicit(&ft_slots_lock, memory_order_release); }

#define FT_FIELD(d, off, type) (*(type *)((char *)(d) + (off)))
#define FT_ARRAY(d, off, type) ((off) < 0 ? (type)NULL : FT_FIELD(d, off, type)) /* -1: an empty array */

/* Point R at the arrays of the MjData d it is called with. */
static void bind_data(ft_run *R, const ft_layout *L, void *d) {
    R->time = &FT_FIELD(d, L->time, double);
    R->ctrl = FT_ARRAY(d, L->ctrl, double *);
    R->qfrc_applied = FT_ARRAY(d, L->qfrc_applied, double *);
    R->userdata = FT_ARRAY(d, L->userdata, double *);
    R->sensordata = FT_ARRAY(d, L->sensordata, const double *);
    R->qvel = FT_ARRAY(d, L->qvel, const double *);
    R->xpos = FT_ARRAY(d, L->xpos, const double *);
    R->xquat = FT_ARRAY(d, L->xquat, const double *);
}

/* The run of d (its arrays bound), or NULL when d belongs to no registered run. */
static ft_run *find_run(void *d) {
    const int high = atomic_load_explicit(&ft_high, memory_order_acquire);
    for (int k = 0; k < high; k++)
        if (atomic_load_explicit(&ft_slots[k].d, memory_order_acquire) == d) {
            ft_run *R = ft_slots[k].R;
            bind_data(R, &ft_slots[k].lay, d);
            return R;
        }
    return NULL;
}

/* One sample's bookkeeping before a step of R (s: the step index). */
static void run_step(ft_run *R, const void *m, void *d) {
    if (R->busy || R->status != FT_RUNNING) return;
    const int64_t s = llround((*R->time - R->t0) / R->h);
    if (s == R->last_step) return;           /* a repeated forward pass at the same time */
    if (s != R->last_step + 1 || s >= R->nsteps) {
        R->status = FT_TIME_JUMP;
        R->bad_time = *R->time;
        return;
    }
    const int n = R->n;
    if (R->integrating && s > 0)             /* the force rate held over the step just done */
        for (int i = 0; i < n; i++) R->qfrc_applied[dof_of(R, i)] += R->force[(s - 1) * n + i];
    R->last_step = s;
    if (s % R->N == 0) {
        run_sample(R, m, d, s);
        return;
    }
    for (int i = 0; i < n; i++) {
        R->ctrl[ctrl_of(R, i)] = R->ctrl_steps[s * n + i];
        if (!R->integrating) R->qfrc_applied[dof_of(R, i)] = R->force[s * n + i];
    }
}

/* The callback installed with mujoco.set_mjcb_control (signature mjfGeneric). */
void ft_control_callback(const void *m, void *d) {
    ft_run *R = find_run(d);
    if (R != NULL) run_step(R, m, d);
}

/* Serve R for the MjData d (layout: d's offsets). Returns 0, or -1 when every slot is taken. */
int32_t ft_run_activate(ft_run *R, void *d, const ft_layout *layout) {
    int32_t found = -1;
    slots_lock();
    int k = 0; /* d's slot if it has one (one run per MjData: the newest activation wins), else a free one */
    while (k < FT_MAXACTIVE && atomic_load_explicit(&ft_slots[k].d, memory_order_relaxed) != d) k++;
    if (k < FT_MAXACTIVE) atomic_store_explicit(&ft_slots[k].d, NULL, memory_order_release);
    else k = 0;
    for (; k < FT_MAXACTIVE; k++) {
        if (atomic_load_explicit(&ft_slots[k].d, memory_order_relaxed) != NULL) continue;
        ft_slots[k].R = R;
        ft_slots[k].lay = *layout;
        atomic_store_explicit(&ft_slots[k].d, d, memory_order_release);
        if (k >= atomic_load(&ft_high)) atomic_store(&ft_high, k + 1);
        found = 0;
        break;
    }
    slots_unlock();
    bind_data(R, layout, d);
    return found;
}

/* d is no longer served by R, without touching d (which may be gone): a run's clean-up. */
void ft_run_forget(ft_run *R, void *d) {
    slots_lock();
    for (int k = 0; k < FT_MAXACTIVE; k++)
        if (atomic_load_explicit(&ft_slots[k].d, memory_order_relaxed) == d && ft_slots[k].R == R)
            atomic_store_explicit(&ft_slots[k].d, NULL, memory_order_release);
    slots_unlock();
}

/* After mj_step(nstep) returned: the increment of the last step done (integrating plants). */
static void run_close(ft_run *R) {
    if (R->integrating && R->status == FT_RUNNING && R->last_step >= 0)
        for (int i = 0; i < R->n; i++) R->qfrc_applied[dof_of(R, i)] += R->force[R->last_step * R->n + i];
}

/* After mj_step(nstep) returned: the last step's increment, and d is no longer served (one call,
 * so that no Python runs between the two). */
void ft_run_finish(ft_run *R, void *d) {
    run_close(R);
    ft_run_forget(R, d);
}

int64_t ft_run_size(void) { return (int64_t)sizeof(ft_run); }

int32_t ft_rmax(void) { return FT_RMAX; }
int64_t ft_law_size(void) { return (int64_t)sizeof(ft_law); }

/* ---- Python extension boilerplate (never imported; see the header comment) -------------------- */
#include <Python.h>

static struct PyModuleDef ft_module = {PyModuleDef_HEAD_INIT, "_kernel",
                                       "C kernel of ftstab_mj, loaded with ctypes", -1, NULL};

PyMODINIT_FUNC PyInit__kernel(void) { return PyModule_Create(&ft_module); }
